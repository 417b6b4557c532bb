"""The fan-out backends (expoctl.parallel) on one small fixed workload: compute_features over 4 sequences of 10
frames (both cameras, 320×240 crops panning over two photos, ORB at native size), n_jobs=2, with

- inprocess (a loop in this process),
- processes (two worker processes from a fork server, one thread each),
- ray, 1 node (a local cluster of one raylet with 2 CPUs),
- ray, 2 nodes (two raylets with 1 CPU each, on this machine),

each timed as the median wall-clock seconds of --repeats runs after one untimed warm-up run (workers and numba
kernels warm), and as a ratio to inprocess. Every run's tables are checked equal to inprocess's.

Run: .venv/bin/python benchmarks/parallel_backends.py [--repeats 3]   (needs the ray extra)
Writes benchmarks/results/parallel_backends.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import skimage.data

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_meta import run_metadata  # noqa: E402
from expoctl.features.pipeline import compute_features  # noqa: E402
from expoctl.io import write_png  # noqa: E402
from expoctl.parallel import ParallelConfig  # noqa: E402

PARAMS = {"frontends": ["orb"], "orb": {"working_size": None, "count_nfeatures": 2000, "match_nfeatures": 1000},
          "seed": 0}
N_JOBS = 2  # worker processes of the processes backend (the ray backend runs one task per cluster CPU)
W, H, N_FRAMES = 320, 240, 10


def make_frames(root: Path) -> pd.DataFrame:
    photos = [skimage.data.astronaut(), skimage.data.coffee(), skimage.data.chelsea(), skimage.data.rocket()]
    rows = []
    for s, photo in enumerate(photos):
        photo = np.asarray(photo)
        for t in range(N_FRAMES):
            for cam in (1, 2):
                x0 = 4 * t + (2 if cam == 2 else 0)
                img = photo[:H, x0:x0 + W]
                rel = f"seq{s}/cam{cam}/{t:06d}.png"
                write_png(np.ascontiguousarray(img), root / rel)
                rows.append({"sequence": f"seq{s}", "frame_id": t, "camera": cam, "image_path": rel})
    return pd.DataFrame(rows)


def time_backend(frames, root, parallel, repeats, reference=None) -> tuple[list[float], tuple]:
    out = compute_features(frames, root, PARAMS, progress=False, parallel=parallel)  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = compute_features(frames, root, PARAMS, progress=False, parallel=parallel)
        times.append(time.perf_counter() - t0)
    if reference is not None:
        for got, want in zip(out, reference):
            pd.testing.assert_frame_equal(got, want)
    return times, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from ray_cluster import local_ray_cluster

    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        frames = make_frames(root / "images")
        images = root / "images"
        times, reference = time_backend(frames, images, ParallelConfig("inprocess"), args.repeats)
        results["inprocess"] = times
        results["processes"], _ = time_backend(frames, images, ParallelConfig("processes", n_jobs=N_JOBS), args.repeats,
                                                   reference)
        for n_nodes in (1, 2):
            # one raylet with both CPUs, or two raylets with one each
            name = f"ray, {n_nodes} node{'s' if n_nodes > 1 else ''}"
            with local_ray_cluster(n_nodes, root / f"ray{n_nodes}", cpus_per_node=2 // n_nodes) as address:
                results[name], _ = time_backend(frames, images, ParallelConfig("ray", address), args.repeats,
                                                reference)
    base = statistics.median(results["inprocess"])
    table = {name: {"median_s": statistics.median(t), "ratio_to_inprocess": statistics.median(t) / base,
                    "runs_s": t} for name, t in results.items()}
    print(f"compute_features, {len(frames)} images in 4 sequences, n_jobs=2, median of {args.repeats}:")
    print(f"{'backend':<14} {'median s':>9} {'× inprocess':>12}")
    for name, row in table.items():
        print(f"{name:<14} {row['median_s']:>9.2f} {row['ratio_to_inprocess']:>12.2f}")
    out = {"workload": {"images": len(frames), "sequences": 4, "size": [W, H], "params": PARAMS,
                        "repeats": args.repeats}, "results": table, "meta": run_metadata(),
           "loadavg": os.getloadavg()}
    path = ROOT / "benchmarks" / "results" / "parallel_backends.json"
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
