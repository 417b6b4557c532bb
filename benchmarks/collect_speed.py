"""Speed of the simulated dual-camera rig (the `collect` stage's inner loop), per frame pair, by part.

    .venv/bin/python benchmarks/collect_speed.py [--frames 20] [--sizes 320x240 640x480]

Times (median over frames, seconds) per frame pair: render camera 1 and camera 2 (ray cast + motion blur over each
camera's own exposure), sensor capture (both), the reference controller (AG+AE), PNG encoding (both). One process;
the renderer's numba kernels use every core. Prints a table and writes benchmarks/results/collect_speed.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import cv2
import numpy as np


def bench(width: int, height: int, n_frames: int) -> dict:
    from expoctl.controllers.registry import make_controller
    import yaml

    from expoctl.camera.sensor import SensorConfig
    from expoctl.sim.closed_loop import RenderConfig, RigConfig, RouteScene, make_sensors, sensor_rng
    from expoctl.sim.protocol import perturb
    from expoctl.world import load_city

    root = Path(__file__).resolve().parents[1]
    world = yaml.safe_load((root / "conf" / "world" / "default.yaml").read_text())
    rig = RigConfig.from_dict(yaml.safe_load((root / "conf" / "rig" / "default.yaml").read_text()))
    render = RenderConfig.from_world(world).with_size(width, height)
    sensor_cfg = yaml.safe_load((root / "conf" / "sensor" / "default.yaml").read_text())
    city = load_city(world["cities"]["train"], str(root / world["city_dir"]))
    t0 = time.perf_counter()
    city.texture_atlas()
    atlas_s = time.perf_counter() - t0
    traj = city.traversal(1, n_frames + 1, rig.fps, 0)
    scene = RouteScene(city, traj, rig, render)
    sensors, _ = make_sensors(SensorConfig.from_dict(sensor_cfg), render, 2, 0.15, 0)
    controller = make_controller("agae", {})
    from expoctl.controllers.base import Settings

    s1 = Settings(0.0, 5000.0)
    controller.reset(s1)
    scene.luminance(0, 1000.0, 1)  # JIT warm-up
    parts: dict[str, list[float]] = {k: [] for k in ("render", "sensor", "controller", "png", "total")}
    for t in range(1, n_frames + 1):
        s2 = perturb(s1, t, 0)
        a = time.perf_counter()
        lum1 = scene.luminance(t, s1.exposure_us, 1)
        lum2 = scene.luminance(t, s2.exposure_us, 2)
        b = time.perf_counter()
        img1 = sensors[0].capture(lum1, s1.exposure_us, s1.gain_db, sensor_rng(0, 1, t))
        img2 = sensors[1].capture(lum2, s2.exposure_us, s2.gain_db, sensor_rng(0, 2, t))
        c = time.perf_counter()
        s1 = controller.update(img1, s1).clamped()
        d = time.perf_counter()
        for img in (img1, img2):
            cv2.imencode(".png", img[..., ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 1])
        e = time.perf_counter()
        for k, v in zip(("render", "sensor", "controller", "png", "total"), (b - a, c - b, d - c, e - d, e - a)):
            parts[k].append(v)
    med = {k: float(np.median(v)) for k, v in parts.items()}
    return {"size": f"{width}x{height}", "frames": n_frames, "atlas_build_s": atlas_s, "median_s": med,
            "frame_pairs_per_s": 1.0 / med["total"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--sizes", nargs="+", default=["320x240", "640x480"])
    args = ap.parse_args()
    rows = []
    for size in args.sizes:
        w, h = (int(x) for x in size.split("x"))
        rows.append(bench(w, h, args.frames))
    print(f"{'size':>8} {'render':>8} {'sensor':>8} {'ctrl':>8} {'png':>8} {'total':>8} {'pairs/s':>8}  (median s per frame pair)")
    for r in rows:
        m = r["median_s"]
        print(f"{r['size']:>8} {m['render']:8.3f} {m['sensor']:8.3f} {m['controller']:8.4f} {m['png']:8.3f} {m['total']:8.3f} "
              f"{r['frame_pairs_per_s']:8.2f}")
    out = Path(__file__).resolve().parent / "results" / "collect_speed.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    meta = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
            "load_avg_1min": os.getloadavg()[0], "command": "benchmarks/collect_speed.py " + " ".join(
                f"--frames {args.frames} --sizes {' '.join(args.sizes)}".split())}
    out.write_text(json.dumps({"meta": meta, "results": rows}, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
