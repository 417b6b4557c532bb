"""Inliers vs exposure at fixed poses, and false detections vs gain at equal brightness (simulator spec, Validation).

    .venv/bin/python benchmarks/archive/exposure_response.py [--width 320 --height 240] [--step-ev 0.5] [--traversals 0 1 2 3]

Part 1 — the inverted U. At fixed poses of a traversal of the `train` city (`open_road`: the point farthest from any
tunnel, in sun or overcast as the traversal draws; `tunnel`: middle of the first tunnel, lamps only, the exit portal
in view ahead; `exit`: 1.5 s before leaving it) the pair (t, t+1) is rendered with motion blur over each exposure
and captured with the EMVA sensor at every setting of the sweep (expoctl.sim.exposure_sweep: 75 µs–30 ms at 0 dB in
`--step-ev` stops, continued with gain at 30 ms where the 30 ms frame is still mostly unclipped). For ORB and the
libviso2-style front end (conf/features) it reports inliers per setting, the argmax and the 90 %-of-max plateau, and
the peak's shift from the open road in EV next to log2 of the scenes' median (and 95th-percentile) luminance ratio.

Part 2 — gain at equal brightness. At a fixed product t·10^(g/20) gain runs 0–30 dB while the exposure shrinks, so
the mean image stays the same. Physics: the collected charge falls as 1/gain, so relative shot noise grows as √gain,
and read noise (fixed in electrons) is multiplied by the gain like the signal; with fewer electrons per DN every DN
of noise is the same in the 8-bit image as a real edge of that contrast. FAST (ORB) and the blob/corner filters of
libviso2 threshold absolute grey differences, so noise alone starts to cross the thresholds. Reported: on the tunnel
pose, features that do not survive matching / RANSAC (n_features − n_inliers, ORB's count detector and viso's dense
features), and detections on a flat field (uniform luminance: every detection is false) at two signal levels.
E.g. a flat field at 5 % of full well at 30 dB holds ~16 e⁻: σ ≈ √(16 + 2.8²) ≈ 4.9 e⁻, 30 % of the signal, ~10
grey levels after the sRGB curve — FAST's threshold of 20 is 2 σ; at 0 dB σ is ~1.4 grey levels and nothing fires.

Writes benchmarks/archive/results/exposure_response.json and docs/exposure_response.png.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT / "src"))

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX  # noqa: E402
from expoctl.features.pipeline import make_frontend  # noqa: E402
from expoctl.io import write_json  # noqa: E402
from bench_meta import run_metadata  # noqa: E402
from expoctl.sim import exposure_sweep as xs  # noqa: E402
from expoctl.camera.sensor import SensorConfig  # noqa: E402
from expoctl.sim.closed_loop import RenderConfig, RigConfig, RouteScene, make_sensors  # noqa: E402
from expoctl.world import load_city  # noqa: E402

POSES = ("open_road", "tunnel", "exit")
FRONTENDS = ("orb", "viso")
PLATEAU_FRACTION = 0.9  # points within 90 % of the best count: how flat the top of the U is


def _conf(name: str) -> dict:
    return yaml.safe_load((ROOT / "conf" / name / "default.yaml").read_text())


def plateau_ev(points, frontend: str) -> tuple[float, float]:
    best = xs.peak(points, frontend).n_inliers[frontend]
    evs = [p.ev for p in points if p.n_inliers[frontend] >= PLATEAU_FRACTION * best]
    return min(evs), max(evs)


def exposure_part(city, rig, render, sensor, fronts, index: int, seed: int, step_ev: float) -> dict:
    traj = city.traversal(index, None, rig.fps, seed)
    scene = RouteScene(city, traj, rig, render)
    frames = xs.pose_frames(city, traj)
    out = {"traversal": index, "overcast": bool(traj.conditions.overcast), "speed_mps": traj.speed_mps, "poses": {}}
    for pose in POSES:
        f = frames[pose]
        lum = scene.luminance(f, EXPOSURE_US_MIN, 1)  # shortest exposure: the scene with least blur
        y = lum @ xs.Y_RGB
        points = xs.sweep_exposure(scene, sensor, f, fronts, seed, step_ev)
        out["poses"][pose] = {
            "frame": f, "median_cd_m2": float(np.median(y)), "p95_cd_m2": float(np.percentile(y, 95)),
            "points": [p.as_dict() for p in points],
            "peak": {fe: {"ev": xs.peak(points, fe).ev, "exposure_us": xs.peak(points, fe).exposure_us,
                          "gain_db": xs.peak(points, fe).gain_db, "n_inliers": xs.peak(points, fe).n_inliers[fe],
                          "mean_grey": xs.peak(points, fe).mean_grey,
                          "saturated_fraction": xs.peak(points, fe).saturated_fraction,
                          "plateau_ev": plateau_ev(points, fe),
                          "n_inliers_first": points[0].n_inliers[fe], "n_inliers_last": points[-1].n_inliers[fe]}
                     for fe in fronts},
        }
    road = out["poses"]["open_road"]
    for pose in POSES[1:]:
        p = out["poses"][pose]
        p["shift"] = {fe: {"peak_shift_ev": p["peak"][fe]["ev"] - road["peak"][fe]["ev"],
                           "log2_median_ratio": math.log2(road["median_cd_m2"] / p["median_cd_m2"]),
                           "log2_p95_ratio": math.log2(road["p95_cd_m2"] / p["p95_cd_m2"])} for fe in fronts}
    return out


def gain_part(city, rig, render, sensor, fronts, index: int, seed: int, tunnel_peak_eff_us: float,
              gain_step_db: float, flat_fractions) -> dict:
    """Equal-brightness gain sweep on the tunnel pose and on flat fields."""
    # the product is the tunnel's ORB peak, clamped so that every gain 0–30 dB has an exposure inside the range
    eff = float(np.clip(tunnel_peak_eff_us, EXPOSURE_US_MIN * 10 ** (GAIN_DB_MAX / 20), EXPOSURE_US_MAX))
    gains = np.arange(0.0, GAIN_DB_MAX + 1e-9, gain_step_db)
    settings = xs.equal_brightness_settings(eff, gains)
    traj = city.traversal(index, None, rig.fps, seed)
    scene = RouteScene(city, traj, rig, render)
    points = xs.sweep_settings(scene, sensor, xs.pose_frames(city, traj)["tunnel"], settings, fronts, seed)
    flat = {}
    for frac in flat_fractions:
        lum = xs.flat_field_luminance_cd_m2(sensor, eff, frac)
        rows = []
        for t, g in settings:
            det, grey = xs.flat_field_detections(sensor, lum, t, g, fronts, seed)
            rows.append({"exposure_us": t, "gain_db": g, "mean_grey": grey, "detections": det})
        flat[str(frac)] = {"luminance_cd_m2": lum, "rows": rows}
    return {"traversal": index, "effective_exposure_us": eff, "tunnel": [p.as_dict() for p in points], "flat": flat}


def print_tables(parts: list[dict], gain: dict, fronts) -> None:
    first = parts[0]
    print(f"\nPart 1a — traversal {first['traversal']}: inliers (t→t+1) per setting; grey = mean grey, sat = clipped share")
    for pose in POSES:
        p = first["poses"][pose]
        print(f"  {pose} (frame {p['frame']}, median {p['median_cd_m2']:.3g} cd/m², p95 {p['p95_cd_m2']:.3g})")
        print(f"    {'exp_us':>7} {'gain':>5} {'EV':>5} {'grey':>5} {'sat':>5} " +
              " ".join(f"{fe + '_feat':>9} {fe + '_inl':>8}" for fe in fronts))
        for q in p["points"]:
            print(f"    {q['exposure_us']:7.0f} {q['gain_db']:5.1f} {q['ev']:5.2f} {q['mean_grey']:5.1f} "
                  f"{q['saturated_fraction']:5.2f} " +
                  " ".join(f"{q['n_features'][fe]:9d} {q['n_inliers'][fe]:8d}" for fe in fronts))
    print("\nPart 1b — peaks per traversal and pose (EV above 75 µs at 0 dB; plateau = EVs within 90 % of the max)")
    print(f"  {'trav':>4} {'sky':8} {'pose':9} {'median':>8} {'fe':5} {'peak_EV':>7} {'exp_us':>7} {'gain':>5} "
          f"{'inl':>5} {'first':>5} {'last':>5} {'plateau':>11} {'shift':>6} {'log2 med':>8} {'log2 p95':>8}")
    for r in parts:
        sky = "overcast" if r["overcast"] else "sun"
        for pose in POSES:
            p = r["poses"][pose]
            for fe in fronts:
                k = p["peak"][fe]
                s = p.get("shift", {}).get(fe)
                tail = (f"{s['peak_shift_ev']:6.1f} {s['log2_median_ratio']:8.2f} {s['log2_p95_ratio']:8.2f}" if s
                        else f"{'':6} {'':8} {'':8}")
                print(f"  {r['traversal']:4d} {sky:8} {pose:9} {p['median_cd_m2']:8.3g} {fe:5} {k['ev']:7.1f} "
                      f"{k['exposure_us']:7.0f} {k['gain_db']:5.1f} {k['n_inliers']:5d} {k['n_inliers_first']:5d} "
                      f"{k['n_inliers_last']:5d} {k['plateau_ev'][0]:5.1f}–{k['plateau_ev'][1]:<5.1f} {tail}")
    print(f"\nPart 2 — gain at equal brightness (t·gain = {gain['effective_exposure_us']:.0f} µs at 0 dB), "
          f"traversal {gain['traversal']}")
    fracs = list(gain["flat"])
    print(f"  {'gain':>5} {'exp_us':>7} {'grey':>5} " + " ".join(
        f"{fe + ' feat':>9} {fe + ' unmatched':>14}" for fe in fronts) + " " + " ".join(
        f"{'flat ' + f + ' ' + fe:>14}" for f in fracs for fe in fronts))
    for i, q in enumerate(gain["tunnel"]):
        flat = " ".join(f"{gain['flat'][f]['rows'][i]['detections'][fe]:14d}" for f in fracs for fe in fronts)
        print(f"  {q['gain_db']:5.1f} {q['exposure_us']:7.0f} {q['mean_grey']:5.1f} " + " ".join(
            f"{q['n_features'][fe]:9d} {q['n_features'][fe] - q['n_inliers'][fe]:14d}" for fe in fronts) + " " + flat)
    print("  flat-field mean grey: " + ", ".join(
        f"{f}: {gain['flat'][f]['rows'][0]['mean_grey']:.1f}–{gain['flat'][f]['rows'][-1]['mean_grey']:.1f}"
        for f in fracs))


def plot(parts: list[dict], gain: dict, fronts, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.5))
    first = parts[0]
    colours = {"open_road": "tab:orange", "tunnel": "tab:blue", "exit": "tab:green"}
    styles = {"orb": "-", "viso": "--"}
    for pose in POSES:
        p = first["poses"][pose]
        ev = [q["ev"] for q in p["points"]]
        for fe in fronts:
            ax1.plot(ev, [q["n_inliers"][fe] for q in p["points"]], styles[fe], color=colours[pose], marker=".",
                     label=f"{pose} {fe} (median {p['median_cd_m2']:.3g} cd/m²)")
            ax1.axvline(p["peak"][fe]["ev"], color=colours[pose], ls=styles[fe], lw=0.6, alpha=0.6)
    ax1.axvline(math.log2(EXPOSURE_US_MAX / EXPOSURE_US_MIN), color="grey", ls=":", lw=1)
    ax1.text(math.log2(EXPOSURE_US_MAX / EXPOSURE_US_MIN) + 0.1, 5, "30 ms → gain", color="grey", fontsize=8)
    ax1.set_xlabel("effective exposure, EV above 75 µs at 0 dB")
    ax1.set_ylabel("inliers (t → t+1)")
    ax1.set_title(f"inliers vs exposure, train traversal {first['traversal']}")
    ax1.legend(fontsize=7)
    g = [q["gain_db"] for q in gain["tunnel"]]
    for fe in fronts:
        ax2.plot(g, [q["n_features"][fe] - q["n_inliers"][fe] for q in gain["tunnel"]], styles[fe], color="tab:blue",
                 marker=".", label=f"tunnel {fe}: n_features − n_inliers")
        for f, c in zip(gain["flat"], ("tab:red", "tab:purple")):
            ax2.plot(g, [r["detections"][fe] for r in gain["flat"][f]["rows"]], styles[fe], color=c, marker=".",
                     label=f"flat field {float(f):.0%} of full well, {fe}")
    ax2.set_xlabel("gain, dB (exposure shrinks: t·gain constant)")
    ax2.set_ylabel("features not explained by the scene")
    ax2.set_title(f"gain at equal brightness ({gain['effective_exposure_us']:.0f} µs·0 dB)")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", default="train")
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--step-ev", type=float, default=0.5)
    ap.add_argument("--traversals", type=int, nargs="+", default=[0, 1, 2, 3],
                    help="traversal indices (lighting, speed); the first one gets the full table, figure and part 2")
    ap.add_argument("--gain-step-db", type=float, default=3.0)
    ap.add_argument("--flat-fractions", type=float, nargs="+", default=[0.05, 0.2],
                    help="flat-field signal as a share of the saturation signal")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "archive" / "results" / "exposure_response.json")
    ap.add_argument("--figure", type=Path, default=ROOT / "docs" / "exposure_response.png")
    args = ap.parse_args()

    world, rig = _conf("world"), RigConfig.from_dict(_conf("rig"))
    render = RenderConfig.from_world(world).with_size(args.width, args.height)
    city = load_city(world["cities"][args.city], str(ROOT / world["city_dir"]))
    sensor = make_sensors(SensorConfig.from_dict(_conf("sensor")), render, 1, 0.0, args.seed)[0][0]
    fcfg = _conf("features")
    fronts = {fe: make_frontend(fe, fcfg.get(fe)) for fe in FRONTENDS}
    t0 = time.perf_counter()
    parts = [exposure_part(city, rig, render, sensor, fronts, i, args.seed, args.step_ev) for i in args.traversals]
    tun = parts[0]["poses"]["tunnel"]["peak"]["orb"]
    gain = gain_part(city, rig, render, sensor, fronts, args.traversals[0], args.seed,
                     tun["exposure_us"] * 10 ** (tun["gain_db"] / 20), args.gain_step_db, args.flat_fractions)
    seconds = time.perf_counter() - t0
    print(f"city {args.city}, {args.width}×{args.height}, step {args.step_ev} EV, {seconds:.0f} s")
    print_tables(parts, gain, FRONTENDS)
    plot(parts, gain, FRONTENDS, args.figure)
    write_json({"city": args.city, "size": [args.width, args.height], "step_ev": args.step_ev, "seed": args.seed,
                "exposure": parts, "gain": gain, "seconds": round(seconds, 1), **run_metadata()}, args.out)
    print(f"wrote {args.out} and {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
