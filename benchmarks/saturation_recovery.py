"""Does a learned controller recover from a badly exposed start? A closed-loop probe of its fixed points.

    .venv/bin/python benchmarks/saturation_recovery.py models/controller.pt models/controller_iter2.pt

Open-loop metrics (validation loss, `closed_loop_gain.py`'s follow) describe a network in the states its training
data contain: camera 1 under a well-exposed reference, camera 2 within about ±1 EV of it. In closed loop the network
also meets states its data never contain, and the worst of them is a saturated frame: it shows almost nothing of the
scene, so nothing in the image tells the network how far to step down. If its step there is about zero, saturation
is an absorbing state and the controller stays white.

The probe drives the real simulator and sensor (train city, a traversal no stage uses, 320×240) in closed loop from
one start frame in the middle of the route's longest open-road (static) section, and one in the middle of its
longest tunnel interior. AG+AE first runs `--frames` frames from its own start to give the reference level P_ref
(its exposure product over the last 10 frames). Then each network runs the same frames, starting at P_ref·2^k for
each offset k (exposure first, then gain), with no warm-up. Per network, start and k, it prints the offset of the
network's exposure product from P_ref over the last 10 frames, the mean step over the first 10 frames, and the
share of clipped pixels (grey ≥ 250) in the last frame. A controller with one attracting fixed point ends at
about the same offset from every k; an absorbing saturated state shows as final offset ≈ k and a step ≈ 0 at large
k. Writes benchmarks/results/saturation_recovery.json.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from expoctl.camera.ranges import exposure_value_ev  # noqa: E402
from expoctl.controllers.agae import split_exposure_first  # noqa: E402
from expoctl.controllers.base import Settings  # noqa: E402
from expoctl.controllers.learned import LearnedController  # noqa: E402
from expoctl.controllers.registry import make_controller  # noqa: E402
from expoctl.io import write_json  # noqa: E402
from bench_meta import run_metadata  # noqa: E402
from expoctl.rig.closed_loop import RenderConfig, RigConfig, RouteScene, make_sensors, run_closed_loop  # noqa: E402
from expoctl.world import load_city  # noqa: E402

TRAVERSAL = 900  # collect uses 0–7 (iteration 1), 100+ and 200+ (later iterations), evaluate its own seeds
SATURATED_DN = 250
LAST = 10  # frames averaged for the final level
FIRST = 10  # frames over which the initial step is averaged


def _conf(name: str) -> dict:
    return yaml.safe_load((ROOT / "conf" / name / "default.yaml").read_text())


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start, length) of the longest run of True in mask."""
    best, start = (0, 0), None
    for i, m in enumerate(np.append(mask, False)):
        if m and start is None:
            start = i
        elif not m and start is not None:
            if i - start > best[1]:
                best = (start, i - start)
            start = None
    return best


def start_frames(traj, n_frames: int) -> dict[str, int]:
    """Middle of the longest static open-road stretch and of the longest stretch inside a tunnel, minus half a run."""
    static = np.asarray(traj.frame_section) == "static"
    t = np.arange(len(static)) / traj.fps
    inside = np.zeros(len(static), bool)  # after an entry crossing and before the next exit
    crossings = sorted(traj.portal_times_s)
    for (t_in, _, kind), nxt in zip(crossings, crossings[1:] + [(math.inf, None, "exit")]):
        if kind == "entry":
            inside |= (t >= t_in) & (t < nxt[0])
    if crossings and crossings[0][2] == "exit":  # the traversal starts inside a tunnel
        inside |= t < crossings[0][0]
    out = {}
    for name, mask in (("open_road", static & ~inside), ("tunnel", inside)):
        s, n = _longest_run(mask)
        if n < n_frames:
            raise SystemExit(f"saturation_recovery: the longest {name} stretch has {n} frames < --frames {n_frames}")
        out[name] = s + (n - n_frames) // 2
    return out


def ev_of(s: Settings) -> float:
    return float(exposure_value_ev(s.gain_db, s.exposure_us))


def run(scene, sensor, controller, initial: Settings, start: int, n: int, seed: int) -> tuple[np.ndarray, float]:
    """Per-frame EV of the applied settings, and the clipped share of the last frame."""
    evs, sat = [], 0.0
    for f in run_closed_loop(scene, [sensor], controller, initial, range(start, start + n), seed):
        cam = f.camera(1)
        evs.append(ev_of(cam.settings))
        sat = float((cam.image.mean(axis=2) >= SATURATED_DN).mean())
    return np.array(evs), sat


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--offsets", type=float, nargs="+", default=[-4.0, -2.0, 0.0, 2.0, 4.0, 6.0], help="EV")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "saturation_recovery.json")
    args = ap.parse_args()
    for ckpt in args.checkpoints:
        if not ckpt.is_file():
            raise SystemExit(f"saturation_recovery: no checkpoint {ckpt}")

    world, rig, sensor_cfg = _conf("world"), RigConfig.from_dict(_conf("rig")), _conf("sensor")
    render = RenderConfig.from_world(world).with_size(args.width, args.height)
    city = load_city(world["cities"]["train"], str(ROOT / world["city_dir"]))
    traj = city.traversal(TRAVERSAL, None, rig.fps, args.seed)
    scene = RouteScene(city, traj, rig, render)
    sensor = make_sensors(sensor_cfg, render, 1, 0.0, args.seed)[0][0]
    agae_cfg = dict(_conf("controllers")["agae"], **{k: v for k, v in sensor_cfg.items()  # resolve ${sensor.*}
                                                      if k.startswith(("response_", "white_balance"))})
    t0 = time.perf_counter()
    results = {"starts": {}, "networks": {}}
    for name, start in start_frames(traj, args.frames).items():
        evs, _ = run(scene, sensor, make_controller("agae", agae_cfg), Settings(0.0, 5000.0), start, args.frames,
                     args.seed)
        ref = float(evs[-LAST:].mean())
        results["starts"][name] = {"frame": int(start), "agae_ref_ev": ref}
    print(f"train city, traversal {TRAVERSAL}, {args.width}×{args.height}, {args.frames} frames per run")
    for name, st in results["starts"].items():  # the camera's ranges clip some starts (e.g. −4 EV in daylight)
        actual = [ev_of(split_exposure_first((st["agae_ref_ev"] + k) * math.log(2.0) + math.log(1e6))) - st["agae_ref_ev"]
                  for k in args.offsets]
        st["start_offsets_ev"] = actual
        print(f"  {name} (frame {st['frame']}): starts at " + ", ".join(f"{a:+.1f}" for a in actual) + " EV from AG+AE")
    print(f"{'network':34s} {'start':9s} " + " ".join(f"{'k=' + format(k, '+g'):>16s}" for k in args.offsets))
    print(f"{'':34s} {'':9s} " + " ".join(f"{'final / step / sat':>16s}" for _ in args.offsets))
    for ckpt in args.checkpoints:
        ctrl = LearnedController.from_checkpoint(ckpt)
        per_start = {}
        for name, st in results["starts"].items():
            rows = []
            for k in args.offsets:
                initial = split_exposure_first((st["agae_ref_ev"] + k) * math.log(2.0) + math.log(1e6))
                evs, sat = run(scene, sensor, ctrl, initial, st["frame"], args.frames, args.seed)
                off = evs - st["agae_ref_ev"]
                rows.append({"k_ev": k, "start_offset_ev": float(off[0]), "final_offset_ev": float(off[-LAST:].mean()),
                             "mean_step_first_ev": float((off[FIRST] - off[0]) / FIRST),
                             "final_saturated_frac": sat, "offset_ev": off.round(3).tolist()})
            per_start[name] = rows
            cells = [f"{r['final_offset_ev']:+5.1f}/{r['mean_step_first_ev']:+5.2f}/{r['final_saturated_frac']:4.2f}"
                     for r in rows]
            print(f"{str(ckpt):34s} {name:9s} " + " ".join(f"{c:>16s}" for c in cells))
        results["networks"][str(ckpt)] = per_start
    seconds = time.perf_counter() - t0
    print(f"(final = offset from AG+AE's level over the last {LAST} frames, EV; step = mean EV per frame over the "
          f"first {FIRST}; sat = clipped share of the last frame) {seconds:.0f} s")
    write_json({"city": "train", "traversal": TRAVERSAL, "size": [args.width, args.height], "frames": args.frames,
                "offsets_ev": args.offsets, **results, "seconds": round(seconds, 1), **run_metadata()}, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
