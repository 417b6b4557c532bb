"""Speed of the libviso2-style front end: ms per 640×480 pair (both frames' features + matching + RANSAC).

Usage: .venv/bin/python benchmarks/viso_speed.py [--repeats N]
Prints a table (median over repeats, per stage) and writes benchmarks/results/viso_speed.json. Warm timings (numba
functions compiled and cached); the cold first-pair time is measured in fresh subprocesses, once with an empty numba
cache (compilation) and once with the on-disk cache (what a pipeline stage pays at start-up).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
STAGES = ["filters", "nms", "descriptors", "matching", "delaunay", "ransac"]
REF_CANDIDATES = [REPO.parent / "shared" / "data" / "viso_reference"]
PAIRS_640 = [
    ("basketball1.png", "basketball2.png"),
    ("Blender_Suzanne1.jpg", "Blender_Suzanne2.jpg"),
    ("aero1.jpg", "aero3.jpg"),
]


def _load_pairs():
    import cv2

    ref = next((d for d in REF_CANDIDATES if (d / "reference.jsonl").exists()), None)
    if ref is not None:
        return [
            (a.rsplit(".", 1)[0], cv2.imread(str(ref / a), cv2.IMREAD_GRAYSCALE), cv2.imread(str(ref / b), cv2.IMREAD_GRAYSCALE))
            for a, b in PAIRS_640
        ]
    # no reference data: a blocky random texture and its translation (640×480)
    rng = np.random.default_rng(0)
    base = np.kron(rng.integers(0, 256, (130, 170), dtype=np.uint8), np.ones((4, 4), np.uint8))
    return [("synthetic translation", base[:480, :640].copy(), base[6:486, 4:644].copy())]


def time_pair(prev_img, cur_img, repeats: int) -> dict:
    from expoctl.features.viso import VisoFrontEnd

    fe = VisoFrontEnd()
    fe.match(fe.extract(prev_img), fe.extract(cur_img), seed=0)  # warm-up (JIT / cache load)
    totals, cpu, per_stage = [], [], {k: [] for k in STAGES}
    counts = None
    for r in range(repeats):
        timings: dict[str, float] = {}
        c0 = time.process_time()
        t0 = time.perf_counter()
        a = fe.extract(prev_img, timings)
        b = fe.extract(cur_img, timings)
        counts = fe.match(a, b, seed=r, timings=timings)
        totals.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        for k in STAGES:
            per_stage[k].append(timings.get(k + ":cpu", 0.0))
    return {
        "wall_ms_median": 1e3 * float(np.median(totals)),
        "wall_ms_min": 1e3 * float(np.min(totals)),
        "cpu_ms_median": 1e3 * float(np.median(cpu)),
        "cpu_ms_median_without_ransac": 1e3 * float(np.median(np.array(cpu) - np.array(per_stage["ransac"]))),
        "stages_cpu_ms_median": {k: 1e3 * float(np.median(v)) for k, v in per_stage.items()},
        "n_features": [fe.n_features(a), fe.n_features(b)],
        "n_matches": int(counts[0]),
        "n_inliers": int(counts[1]),
    }


_COLD_SNIPPET = """
import time, numpy as np
t0 = time.perf_counter()
from expoctl.features.viso import VisoFrontEnd
rng = np.random.default_rng(0)
base = np.kron(rng.integers(0, 256, (130, 170), dtype=np.uint8), np.ones((4, 4), np.uint8))
fe = VisoFrontEnd()
fe.match(fe.extract(base[:480, :640].copy()), fe.extract(base[6:486, 4:644].copy()), seed=0)
print(time.perf_counter() - t0)
"""


def cold_first_pair_s(empty_cache: bool) -> float:
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as tmp:
        if empty_cache:
            env["NUMBA_CACHE_DIR"] = tmp
        out = subprocess.run([sys.executable, "-c", _COLD_SNIPPET], env=env, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "viso_speed.json"))
    args = ap.parse_args(argv)

    results = {}
    for name, a, b in _load_pairs():
        results[name] = time_pair(a, b, args.repeats)
    cold_compile = cold_first_pair_s(empty_cache=True)
    cold_cached = cold_first_pair_s(empty_cache=False)

    head = f"{'pair (640×480)':17s} {'wall':>6s} {'wall min':>8s} {'CPU':>6s} {'CPU-RANSAC':>10s} | "
    print(head + " ".join(f"{k:>11s}" for k in STAGES) + "   features      A     C")
    for name, r in results.items():
        print(
            f"{name:17s} {r['wall_ms_median']:6.1f} {r['wall_ms_min']:8.1f} {r['cpu_ms_median']:6.1f} "
            f"{r['cpu_ms_median_without_ransac']:10.1f} | "
            + " ".join(f"{r['stages_cpu_ms_median'][k]:11.1f}" for k in STAGES)
            + f"   {r['n_features'][0]:4d}/{r['n_features'][1]:4d} {r['n_matches']:5d} {r['n_inliers']:5d}"
        )
    print(f"(ms per pair over {args.repeats} repeats: wall median and min, process CPU median with and without the "
          f"RANSAC count; stages: CPU medians, both frames; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores; the pipeline is single-threaded, so CPU time is its speed on an idle core)")
    print(f"cold first pair in a fresh process: {cold_compile:.1f} s with an empty numba cache (JIT compile), "
          f"{cold_cached:.2f} s with the on-disk cache")

    from expoctl.io import write_json

    write_json(
        {
            "unit": "ms per pair (both frames' extraction + matching + F-RANSAC count C); stages in CPU ms",
            "repeats": args.repeats,
            "target_ms": 80,
            "pairs": results,
            "cold_first_pair_s": {"empty_numba_cache": cold_compile, "with_numba_cache": cold_cached},
            "machine": {"cpu_count": os.cpu_count(), "load_average_1min": os.getloadavg()[0]},
        },
        args.out,
    )
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
