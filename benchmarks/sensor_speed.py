"""Speed of the sensor stage (scene luminance → delivered 8-bit RGB, and → linear raw DN) at render sizes.

Usage: .venv/bin/python benchmarks/sensor_speed.py [--repeats 30] [--sizes 640x480,320x240]
Prints a table and writes benchmarks/results/sensor_speed.json. Single process; medians of wall-clock time per call
(the first call per size is a warm-up: numba's cached kernels load on first use).

Scenes: a tunnel-exit-like frame (log-uniform luminance 1–10,000 cd/m²), captured at settings that put most pixels
in the Gaussian shot-noise path (`bright`), and a dark tunnel at short exposure where many pixels take exact Poisson
draws (`dark`, the slow path). Spec target: sensor stage ~15–20 ms at 640×480 in numpy on one core.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from expoctl.camera.sensor import Sensor, SensorConfig  # noqa: E402
from expoctl.io import write_json  # noqa: E402

SCENES = {
    # name: (log10 luminance range cd/m², exposure µs, gain dB)
    "bright_exit": ((0.0, 4.0), 2000.0, 0.0),
    "dark_tunnel": ((-1.0, 1.0), 200.0, 24.0),
}


def _median_ms(fn, repeats: int) -> tuple[float, float, float]:
    fn()  # warm-up
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(1e3 * (time.perf_counter() - w0))
        cpu.append(1e3 * (time.process_time() - c0))
    return float(np.median(wall)), float(np.median(cpu)), float(np.percentile(wall, 90))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--sizes", default="640x480,320x240")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "sensor_speed.json")
    args = ap.parse_args()
    sizes = [tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")]

    cfg = SensorConfig()
    rows = []
    for width, height in sizes:
        sensor = Sensor(cfg, height, width, seed=1)
        scene_rng = np.random.default_rng(0)
        for scene, ((lo, hi), exposure_us, gain_db) in SCENES.items():
            lum = (10.0 ** scene_rng.uniform(lo, hi, (height, width, 3))).astype(np.float32)
            mu = sensor.mean_electrons(lum, exposure_us)
            poisson_share = float((mu < cfg.poisson_exact_below).mean())
            rng = np.random.default_rng(1)
            for call, fn in (("capture (8-bit)", lambda: sensor.capture(lum, exposure_us, gain_db, rng)),
                             ("capture_raw (DN)", lambda: sensor.capture_raw(lum, exposure_us, gain_db, rng))):
                wall, cpu, p90 = _median_ms(fn, args.repeats)
                rows.append({"size": f"{width}x{height}", "scene": scene, "call": call, "exposure_us": exposure_us,
                             "gain_db": gain_db, "exact_poisson_share": poisson_share, "median_wall_ms": wall,
                             "median_cpu_ms": cpu, "p90_wall_ms": p90})

    print(f"{'size':9s} {'scene':12s} {'call':17s} {'Poisson px':>10s} {'wall ms':>8s} {'cpu ms':>7s} {'p90 ms':>7s}")
    for r in rows:
        print(f"{r['size']:9s} {r['scene']:12s} {r['call']:17s} {r['exact_poisson_share']:10.1%} "
              f"{r['median_wall_ms']:8.1f} {r['median_cpu_ms']:7.1f} {r['p90_wall_ms']:7.1f}")
    load = os.getloadavg()[0]
    print(f"load average (1 min) {load:.1f} on {os.cpu_count()} cores — shared machine, wall times include contention")
    write_json({"repeats": args.repeats, "rows": rows, "load_average_1min": load, "cpu_count": os.cpu_count(),
                "numba_threads": "default (kernels are serial)"}, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
