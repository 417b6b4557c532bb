"""Realism of the simulated images for feature matching: ORB inlier counts between consecutive frames (not a test).

docs/simulator.md (World design targets) gives the target from a prototype: ORB with 1,500 features on 640×480-class
images, ~120–280 inlier matches between consecutive frames on textured road scenes (near-flat walls ~50 keypoints).
This drives camera 1 of the simulated rig under AG+AE through a whole traversal passage of a tunnel (closed loop, every
frame rendered, `--before-s` seconds ahead of the entry to `--after-s` past the exit) and, every `--every` frames,
counts ORB inliers for the pair (t, t+1) exactly as that prototype did: ORB 1,500 at the native render size,
cross-checked Hamming brute force, fundamental-matrix RANSAC (3 px, 0.99). Also the pipeline's own ORB set-up
(conf/features: 2,000 match features at a 512×384 working size) on the same pairs. Percentiles per section
(outside = static frames, tunnel transitions = dynamic frames).

    .venv/bin/python benchmarks/archive/orb_realism.py [--city train] [--sizes 640x480 320x240] [--every 3]

Prints a table and writes benchmarks/results/orb_realism.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT / "src"))

from expoctl.controllers.base import Settings  # noqa: E402
from expoctl.controllers.registry import make_controller  # noqa: E402
from expoctl.features.orb import OrbFrontEnd  # noqa: E402
from expoctl.features.pipeline import rgb_to_grey  # noqa: E402
from expoctl.io import write_json  # noqa: E402
from bench_meta import run_metadata  # noqa: E402
from expoctl.camera.sensor import SensorConfig  # noqa: E402
from expoctl.sim.closed_loop import RenderConfig, RigConfig, RouteScene, make_sensors, run_closed_loop  # noqa: E402
from expoctl.world import load_city  # noqa: E402

SPEC_RANGE = (120, 280)


def _conf(name: str) -> dict:
    return yaml.safe_load((ROOT / "conf" / name / "default.yaml").read_text())


def measure(city_name: str, width: int, height: int, every: int, before_s: float, after_s: float, seed: int) -> dict:
    world, rig = _conf("world"), RigConfig.from_dict(_conf("rig"))
    render = RenderConfig.from_world(world).with_size(width, height)
    city = load_city(world["cities"][city_name], str(ROOT / world["city_dir"]))
    lap = city.traversal(0, None, rig.fps, seed)
    traj = city.traversal(0, 2 * len(lap.timestamps_ns), rig.fps, seed)
    entry = next(tc for tc, _, kind in traj.portal_times_s if kind == "entry")
    exit_ = next(tc for tc, _, kind in traj.portal_times_s if kind == "exit" and tc > entry)
    start, stop = int((entry - before_s) * rig.fps), int((exit_ + after_s) * rig.fps)
    scene = RouteScene(city, traj, rig, render)
    sensors, _ = make_sensors(SensorConfig.from_dict(_conf("sensor")), render, 1, 0.0, seed)
    fcfg = _conf("features")["orb"]
    fronts = {
        "spec_orb1500_native": OrbFrontEnd({**fcfg, "working_size": None, "match_nfeatures": 1500}),
        "pipeline_orb": OrbFrontEnd(fcfg),
    }
    counts = {k: {"static": [], "dynamic": []} for k in fronts}
    prev = None
    t0 = time.perf_counter()
    frames = run_closed_loop(scene, sensors, make_controller("agae", {}), Settings(0.0, 5000.0), range(start, stop),
                             seed, warmup_frames=60)
    for fr in frames:
        grey = rgb_to_grey(fr.cameras[0].image)
        t = fr.frame_index
        if prev is not None and (t - start) % every == 1:
            kind = str(traj.frame_section[t - 1])
            for name, fe in fronts.items():
                counts[name][kind].append(fe.match(fe.extract(prev), fe.extract(grey), seed=t)[1])
        prev = grey
    seconds = time.perf_counter() - t0

    def stats(v):
        v = np.asarray(v, float)
        if not v.size:
            return None
        p = np.percentile(v, [5, 25, 50, 75, 95])
        return {"pairs": int(v.size), "p5": p[0], "p25": p[1], "median": p[2], "p75": p[3], "p95": p[4],
                "share_in_spec_range": float(np.mean((v >= SPEC_RANGE[0]) & (v <= SPEC_RANGE[1])))}

    return {"city": city_name, "size": f"{width}x{height}", "frames": [start, stop], "every": every,
            "seconds": round(seconds, 1),
            "inliers": {n: {k: stats(v) for k, v in c.items()} for n, c in counts.items()}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--city", default="train")
    ap.add_argument("--sizes", nargs="+", default=["640x480", "320x240"])
    ap.add_argument("--every", type=int, default=3, help="measure every k-th frame pair")
    ap.add_argument("--before-s", type=float, default=4.0)
    ap.add_argument("--after-s", type=float, default=4.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "archive" / "results" / "orb_realism.json")
    args = ap.parse_args()
    rows = []
    for size in args.sizes:
        w, h = (int(x) for x in size.split("x"))
        rows.append(measure(args.city, w, h, args.every, args.before_s, args.after_s, args.seed))
    print(f"ORB inliers between consecutive frames, city {args.city}, AG+AE, spec target {SPEC_RANGE[0]}–"
          f"{SPEC_RANGE[1]} (ORB 1500, 640×480-class)")
    print(f"{'size':>8} {'ORB set-up':22s} {'section':8s} {'pairs':>5} {'p5':>5} {'p25':>5} {'median':>6} {'p75':>5} "
          f"{'p95':>5} {'in range':>8}")
    for r in rows:
        for name, per in r["inliers"].items():
            for kind, s in per.items():
                if s:
                    print(f"{r['size']:>8} {name:22s} {kind:8s} {s['pairs']:5d} {s['p5']:5.0f} {s['p25']:5.0f} "
                          f"{s['median']:6.0f} {s['p75']:5.0f} {s['p95']:5.0f} {s['share_in_spec_range']:8.0%}")
    write_json({"spec_range": SPEC_RANGE, "results": rows, **run_metadata()}, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
