"""AG+AE against the real camera's recorded tunnel pass: the fit, and the simulated tunnel passes side by side.

The real rig's camera 1 (FLIR Blackfly S, built-in AG+AE) recorded its exposure and gain per frame through one tunnel
(`data_32`, shared/data/authors_settings). This prints, for the recording and for the model driven through simulated
tunnel passes of the configured cities (the same statistics, `expoctl.controllers.ae_trace`):
- per section (entry rise, exit fall, outdoor after) and direction: number of moves, median, p90 and largest step;
- exit: largest reducing step, mean rate over 80 % of the drop, frames for 80 % and to settle, onset ramp;
- entry: first (largest) increase and the shrink ratio of consecutive increases;
- the outdoor exposure at 0 dB before the entry and after the exit (recorded: 1.45–2.3 ms).
It does this for the configured AG+AE (settings land at t+2) and for one more frame of latency (t+3), and with
`--old` also for the loop before the fit. No NFM or VO is computed: the fit is decided on these statistics alone.

A simulated pass starts `--before-s` before a tunnel entry and ends `--after-s` after its exit, with `--warmup` frames
(default 90, 6 s) so that AG+AE has settled outdoors, like the recorded pass (which starts at the entry).

    .venv/bin/python benchmarks/archive/agae_fit.py [--cities train validation] [--passes 4] [--width 320] [OVERRIDE ...]

OVERRIDEs are Hydra overrides as in params.yaml. Writes benchmarks/results/agae_fit.json.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path[:0] = [str(ROOT / "src"), str(ROOT)]

from bench_meta import run_metadata  # noqa: E402

from expoctl.controllers.ae_trace import entry_stats, ev_trace, exit_stats, step_table  # noqa: E402
from expoctl.controllers.agae import AgAeController  # noqa: E402
from expoctl.controllers.base import Settings  # noqa: E402
from expoctl.errors import ConfigError, InputError  # noqa: E402
from expoctl.io import write_json  # noqa: E402
from expoctl.camera.sensor import SensorConfig  # noqa: E402
from expoctl.sim.closed_loop import RenderConfig, RigConfig, RouteScene, make_sensors, run_closed_loop  # noqa: E402
from expoctl.world import load_world_city  # noqa: E402
from stages.compose import compose_config  # noqa: E402

RECORDING = ROOT.parent / "shared" / "data" / "authors_settings" / "data_32.csv"
RECORDED_EXIT_START = 60  # the recorded pass: entry at frame 0, exit at ~73–125 (docs/calibration.md)
RECORDED_OUTDOOR_US = (1450.0, 2300.0)  # camera 1 outdoors at 0 dB before the entry and after the exit (docs/calibration.md)
OLD_LOOP = {"damping": 0.2, "max_brighten_ev_per_frame": 0.5, "max_darken_ev_per_frame": 0.5}


def trace_summary(ev: np.ndarray, exit_from: int, exposure_us: np.ndarray, gain_db: np.ndarray,
                  outdoor_before: slice, outdoor_after: slice) -> dict:
    """All statistics of one pass. `exit_from`: a frame inside the tunnel after the entry's transient."""
    out: dict = {"sections": {"entry": step_table(ev[: exit_from + 1]), "exit": step_table(ev[exit_from:])}}
    try:
        out["exit"] = exit_stats(ev[exit_from:]).to_dict()
    except ValueError as exc:
        out["exit"] = {"error": str(exc)}
    try:
        out["entry"] = entry_stats(ev[: exit_from + 1]).to_dict()
    except ValueError as exc:
        out["entry"] = {"error": str(exc)}

    def outdoor(sl):
        t, g = exposure_us[sl], gain_db[sl]
        return {"median_exposure_us": float(np.median(t)), "median_gain_db": float(np.median(g))} if t.size else None

    out["outdoor_before"], out["outdoor_after"] = outdoor(outdoor_before), outdoor(outdoor_after)
    return out


def recorded(path: Path) -> dict:
    try:
        d = pd.read_csv(path)
    except (OSError, pd.errors.ParserError) as exc:
        raise InputError(f"{path}: {exc}") from None
    missing = {"frame_id", "camera", "exposure_us", "gain_db"} - set(d.columns)
    if missing:
        raise InputError(f"{path}: missing column(s) {sorted(missing)}")
    c = d[d["camera"] == 1].sort_values("frame_id")
    t, g = c["exposure_us"].to_numpy(float), c["gain_db"].to_numpy(float)
    ev = ev_trace(t, g)
    s = trace_summary(ev, RECORDED_EXIT_START, t, g, slice(0, 2), slice(len(ev) - 60, len(ev)))
    s["frames"] = int(len(ev))
    return s


def tunnel_passes(city, n: int, fps: float, before_s: float, after_s: float, warmup: int):
    """Up to n (trajectory, first frame, last frame + 1, exit frame, entry frame) passes through the city's tunnels,
    one per traversal index (trying up to 4n indices), cycling over the tunnels; frames are relative to the pass."""
    spans = city.tunnel_spans()
    passes = []
    for i in range(4 * n):
        if len(passes) == n:
            break
        traj = city.traversal(i, None, fps=fps, seed=0)
        ti = i % len(spans)
        times = {kind: t for t, k, kind in traj.portal_times_s if k == ti}
        entries = [t for t, k, kind in traj.portal_times_s if k == ti and kind == "entry"]
        exits = [t for t, k, kind in traj.portal_times_s if k == ti and kind == "exit"]
        pair = next(((a, b) for a in entries for b in exits if b > a), None)
        if pair is None or not times:
            continue
        a = int(math.floor((pair[0] - before_s) * fps))
        b = int(math.ceil((pair[1] + after_s) * fps))
        if a < warmup or b > len(traj.timestamps_ns):
            continue  # the pass is cut by the start or end of the lap: skip it rather than shorten it
        passes.append((traj, a, b, int(round(pair[1] * fps)) - a, int(round(pair[0] * fps)) - a))
    return passes


def simulate(cfg: dict, split: str, agae_params: dict, n_passes: int, width: int, height: int,
             before_s: float, after_s: float, warmup: int) -> list[dict]:
    city = load_world_city(cfg["world"], split)
    rig = RigConfig.from_dict(cfg["rig"])
    render = RenderConfig.from_world(cfg["world"]).with_size(width, height)
    sensors, _ = make_sensors(SensorConfig.from_dict(cfg["sensor"]), render, 1, 0.0, seed=0)
    out = []
    for traj, a, b, exit_k, entry_k in tunnel_passes(city, n_passes, rig.fps, before_s, after_s, warmup):
        scene = RouteScene(city, traj, rig, render)
        ctrl = AgAeController(agae_params)
        frames = list(run_closed_loop(scene, sensors, ctrl, Settings(0.0, 2000.0), range(a, b), seed=traj.index,
                                      warmup_frames=warmup))
        t = np.array([f.camera(1).settings.exposure_us for f in frames])
        g = np.array([f.camera(1).settings.gain_db for f in frames])
        sat = np.array([float((f.camera(1).image.max(axis=2) >= 250).mean()) for f in frames])
        ev = ev_trace(t, g)
        # the exit statistics start halfway through the tunnel, past the entry's transient
        s = trace_summary(ev, (entry_k + exit_k) // 2, t, g, slice(0, max(1, entry_k - int(0.5 * rig.fps))),
                          slice(len(ev) - 15, len(ev)))
        s.update(traversal=traj.index, overcast=bool(traj.conditions.overcast), frames=int(len(ev)),
                 sun_elevation_deg=float(np.degrees(np.arcsin(traj.conditions.sun_direction[2]))),
                 exit_frame=exit_k, entry_frame=entry_k,
                 frames_over_half_saturated_after_exit=int((sat[exit_k:] > 0.5).sum()),
                 global_illuminance_lux=float(traj.conditions.global_illuminance_lux))
        out.append(s)
    return out


def _fmt(v, spec):
    return format(v, spec) if isinstance(v, (int, float)) and math.isfinite(v) else "—"


def print_row(name: str, s: dict) -> None:
    e, n = s.get("exit", {}), s.get("entry", {})
    ob, oa = s.get("outdoor_before") or {}, s.get("outdoor_after") or {}
    print(f"{name:34s} {_fmt(e.get('largest_reducing_step_ev'), '6.3f')} {_fmt(e.get('mean_rate_80_ev_per_frame'), '7.3f')}"
          f" {_fmt(e.get('frames_80'), '4d')} {_fmt(e.get('frames_to_settle'), '6d')} {_fmt(e.get('onset_frames'), '5d')}"
          f" | {_fmt(n.get('first_step_ev'), '5.2f')} {_fmt(n.get('shrink_ratio'), '6.3f')}"
          f" | {_fmt(ob.get('median_exposure_us'), '7.0f')} {_fmt(oa.get('median_exposure_us'), '7.0f')}"
          f" {_fmt(s.get('frames_over_half_saturated_after_exit'), '4d')}")


def median_of(runs: list[dict], path: tuple) -> float:
    vals = []
    for r in runs:
        v = r
        for p in path:
            v = v.get(p) if isinstance(v, dict) else None
        if isinstance(v, (int, float)):
            vals.append(float(v))
    return float(np.median(vals)) if vals else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("overrides", nargs="*", help="Hydra overrides (as in params.yaml)")
    ap.add_argument("--cities", nargs="+", default=["train", "validation"], help="world.cities splits to drive")
    ap.add_argument("--passes", type=int, default=4, help="tunnel passes per city (one per traversal)")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--before-s", type=float, default=3.0)
    ap.add_argument("--after-s", type=float, default=6.0)
    ap.add_argument("--warmup", type=int, default=90, help="frames AG+AE runs before the pass (settles outdoors)")
    ap.add_argument("--old", action="store_true", help="also drive the loop before the fit")
    ap.add_argument("--recording", type=Path, default=RECORDING)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "archive" / "results" / "agae_fit.json")
    args = ap.parse_args()
    t0 = time.time()
    try:
        rec = recorded(args.recording)
        cfg = compose_config(list(args.overrides))
        base = dict(cfg["controllers"]["agae"])
        variants = {"fitted, lands at t+2": base,
                    "fitted, lands at t+3": dict(base, internal_latency_frames=base["internal_latency_frames"] + 1)}
        if args.old:
            variants["old loop (damping 0.2, ±0.5 EV)"] = dict(base, **OLD_LOOP)
        sims = {name: {split: simulate(cfg, split, params, args.passes, args.width, args.height, args.before_s,
                                       args.after_s, args.warmup) for split in args.cities}
                for name, params in variants.items()}
    except (ConfigError, InputError, ValueError) as exc:
        print(f"agae_fit: {exc}", file=sys.stderr)
        return 2

    print(f"AG+AE tunnel passes at {args.width}x{args.height} (recorded: data_32, camera 1)")
    print(f"{'':34s} {'exit: ':6s}{'mean80':>7s} {'n80':>4s} {'settle':>6s} {'onset':>5s} | {'entry':>5s} {'shrink':>6s}"
          f" | {'out t0':>7s} {'out t1':>7s} {'>50%':>4s}")
    print(f"{'':34s} {'max':>6s} {'EV/fr':>7s} {'fr':>4s} {'fr':>6s} {'fr':>5s} | {'1st':>5s} {'ratio':>6s}"
          f" | {'µs':>7s} {'µs':>7s} {'sat':>4s}")
    print_row("recorded (data_32)", rec)
    summary = {}
    for name, by_city in sims.items():
        for split, runs in by_city.items():
            for r in runs:
                print_row(f"{name[:22]} {split[:5]} #{r['traversal']}{' oc' if r['overcast'] else ''}", r)
            keys = {"largest_reducing_step_ev": ("exit", "largest_reducing_step_ev"),
                    "mean_rate_80_ev_per_frame": ("exit", "mean_rate_80_ev_per_frame"),
                    "frames_80": ("exit", "frames_80"), "frames_to_settle": ("exit", "frames_to_settle"),
                    "onset_frames": ("exit", "onset_frames"), "entry_first_step_ev": ("entry", "first_step_ev"),
                    "entry_shrink_ratio": ("entry", "shrink_ratio"),
                    "outdoor_exposure_us": ("outdoor_after", "median_exposure_us"),
                    "frames_over_half_saturated_after_exit": ("frames_over_half_saturated_after_exit",)}
            summary.setdefault(name, {})[split] = {k: median_of(runs, p) for k, p in keys.items()}
    print("\nmedians over passes vs recorded (ratio sim/recorded; done-criterion band ±30 % on the first two)")
    for name, by_city in summary.items():
        for split, m in by_city.items():
            r1 = m["largest_reducing_step_ev"] / rec["exit"]["largest_reducing_step_ev"]
            r2 = m["mean_rate_80_ev_per_frame"] / rec["exit"]["mean_rate_80_ev_per_frame"]
            print(f"  {name:32s} {split:10s} largest step {m['largest_reducing_step_ev']:.3f} ({r1:.2f}x)  "
                  f"mean rate {m['mean_rate_80_ev_per_frame']:.3f} ({r2:.2f}x)  onset {m['onset_frames']:.0f} "
                  f"(rec {rec['exit']['onset_frames']})  entry ratio {m['entry_shrink_ratio']:.3f}  "
                  f"outdoor {m['outdoor_exposure_us']:.0f} µs")
    # sensitivity: AG+AE's outdoor exposure at 0 dB scales with the f-number squared (same scene, same target grey),
    # so the aperture that puts the median pre-entry exposure at the recorded range's geometric centre is
    # N·sqrt(t_rec / t_sim). Computed from the first variant, over every pass of every city driven.
    first = next(iter(sims.values()))
    outdoor = [r["outdoor_before"]["median_exposure_us"] for runs in first.values() for r in runs
               if r.get("outdoor_before") and r["outdoor_before"]["median_gain_db"] < 0.05]
    aperture = None
    if outdoor:
        t_rec = math.sqrt(RECORDED_OUTDOOR_US[0] * RECORDED_OUTDOOR_US[1])
        t_sim = float(np.median(outdoor))
        n_now = float(cfg["sensor"]["f_number"])
        aperture = {"f_number_now": n_now, "median_outdoor_us": t_sim, "passes": len(outdoor),
                    "outdoor_us_range": [float(min(outdoor)), float(max(outdoor))],
                    "recorded_outdoor_us": list(RECORDED_OUTDOOR_US), "implied_f_number": n_now * math.sqrt(t_rec / t_sim)}
        print(f"\nsensitivity: median outdoor exposure before the entry {t_sim:.0f} µs at 0 dB over {len(outdoor)} passes "
              f"(range {min(outdoor):.0f}–{max(outdoor):.0f}) at f/{n_now:g}; the recorded "
              f"{RECORDED_OUTDOOR_US[0]:.0f}–{RECORDED_OUTDOOR_US[1]:.0f} µs (centre {t_rec:.0f}) implies "
              f"f/{aperture['implied_f_number']:.2f}")
    write_json({"overrides": list(args.overrides), "resolution": [args.width, args.height], "recorded": rec,
                "aperture": aperture,
                "variants": {k: {"params": variants[k], "passes": sims[k], "medians": summary[k]} for k in variants},
                "seconds": round(time.time() - t0, 1), **run_metadata()}, args.out)
    print(f"wrote {args.out} ({time.time() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
