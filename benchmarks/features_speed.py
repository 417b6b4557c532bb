"""Speed of the feature front ends and of the features stage's library.

1. ms per 640×480 pair (extract both images + match + verify) for each front end that imports (orb; viso), on two
   realistic pairs: the Middlebury motorcycle stereo pair (real parallax) and the coffee photo under a small
   rotation/zoom/shift (a camera turning). Median of repeated runs.
2. images/s of compute_features on a small generated set (two sequences of 12 frames panning over the motorcycle
   photo, both cameras, 640×480), in-process (n_jobs=1) and with the process pool (n_jobs=2, cold then warm).

Run: .venv/bin/python benchmarks/features_speed.py [--repeats 7]
Writes benchmarks/results/features_speed.json. The machine is shared: load average is recorded with the numbers.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import skimage.data

from expoctl.features.pipeline import compute_features, make_frontend, match_images, rgb_to_grey
from expoctl.io import write_json, write_png

W, H = 640, 480
RESULTS = Path(__file__).resolve().parent / "results" / "features_speed.json"


def realistic_pairs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    left, right, _ = skimage.data.stereo_motorcycle()  # 500×741 RGB
    stereo = (rgb_to_grey(left[10:10 + H, 50:50 + W]), rgb_to_grey(right[10:10 + H, 50:50 + W]))
    coffee = cv2.resize(rgb_to_grey(skimage.data.coffee()), (W, H), interpolation=cv2.INTER_LINEAR)
    warp = cv2.getRotationMatrix2D((W / 2, H / 2), 1.5, 1.03)  # 1.5° roll, 3 % zoom
    warp[:, 2] += (8, -5)
    coffee_cur = cv2.warpAffine(coffee, warp, (W, H), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return {"motorcycle_stereo": stereo, "coffee_warped": (coffee, coffee_cur)}


def available_frontends() -> list[str]:
    names = []
    for name in ("orb", "viso"):
        try:
            make_frontend(name, {})
            names.append(name)
        except ImportError as exc:
            print(f"front end {name} not available: {exc}", file=sys.stderr)
    return names


def time_pairs(frontends, pairs, repeats) -> list[dict]:
    rows = []
    for name in frontends:
        fe = make_frontend(name, {})
        for pair_name, (a, b) in pairs.items():
            match_images(fe, a, b)  # warm-up (numba compilation, OpenCV lazy init)
            times, counts = [], None
            for k in range(repeats):
                t0 = time.perf_counter()
                counts = match_images(fe, a, b, seed=k)
                times.append(time.perf_counter() - t0)
            rows.append({"frontend": name, "pair": pair_name, "ms_per_pair_median": 1000 * statistics.median(times),
                         "ms_per_pair_min": 1000 * min(times), "repeats": repeats,
                         "n_features_prev": counts.n_features_prev, "n_matches": counts.n_matches,
                         "n_inliers": counts.n_inliers})
    return rows


def generated_project(root: Path, n_sequences=2, n_frames=12) -> pd.DataFrame:
    left, _, _ = skimage.data.stereo_motorcycle()
    big = cv2.resize(left, (int(741 * 1.3), int(500 * 1.3)), interpolation=cv2.INTER_LINEAR)  # 963×650
    rows = []
    for s in range(n_sequences):
        for t in range(n_frames):
            for cam in (1, 2):
                x0, y0 = 20 * s + 12 * t + (3 if cam == 2 else 0), 30 + 4 * s
                gain = 1.0 if cam == 1 else 1.4
                img = np.clip(big[y0:y0 + H, x0:x0 + W].astype(np.float32) * gain, 0, 255).astype(np.uint8)
                rel = f"raw/seq{s}/cam{cam}/{t:06d}.png"
                write_png(img, root / rel)
                rows.append({"sequence": f"seq{s}", "frame_id": t, "camera": cam, "image_path": rel})
    return pd.DataFrame(rows)


def time_compute_features(frontends, n_jobs_list) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        frames = generated_project(Path(tmp))
        for fronts in ([["orb"]] + ([frontends] if len(frontends) > 1 else [])):
            for run, n_jobs in enumerate(n_jobs_list):
                params = {"frontends": fronts}
                t0 = time.perf_counter()
                feats, matches = compute_features(frames, tmp, params, n_jobs=n_jobs, progress=False)
                seconds = time.perf_counter() - t0
                rows.append({"frontends": "+".join(fronts), "n_jobs": n_jobs, "run": run, "n_images": len(frames),
                             "n_pair_rows": len(matches), "seconds": seconds, "images_per_s": len(frames) / seconds,
                             "median_n_inliers": float(matches.n_inliers.median())})
    return rows


def _git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=Path(__file__).parent, capture_output=True,
                              text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    frontends = available_frontends()
    load_before = os.getloadavg()
    pair_rows = time_pairs(frontends, realistic_pairs(), args.repeats)
    # n_jobs=2 twice: the first pays the pool start (fork server, numba init per worker), the second runs warm
    cf_rows = time_compute_features(frontends, [1, 2, 2])
    load_after = os.getloadavg()

    print(f"\nms per {W}×{H} pair (extract both + match + F-RANSAC), median of {args.repeats}")
    print(f"{'frontend':<9}{'pair':<20}{'median ms':>10}{'min ms':>9}{'features':>10}{'matches':>9}{'inliers':>9}")
    for r in pair_rows:
        print(f"{r['frontend']:<9}{r['pair']:<20}{r['ms_per_pair_median']:>10.1f}{r['ms_per_pair_min']:>9.1f}"
              f"{r['n_features_prev']:>10}{r['n_matches']:>9}{r['n_inliers']:>9}")
    print(f"\ncompute_features on {cf_rows[0]['n_images']} generated {W}×{H} images (2 sequences × 12 frames × 2 cameras)")
    print(f"{'frontends':<12}{'n_jobs':>7}{'run':>4}{'seconds':>9}{'images/s':>10}{'median inliers':>16}")
    for r in cf_rows:
        print(f"{r['frontends']:<12}{r['n_jobs']:>7}{r['run']:>4}{r['seconds']:>9.2f}{r['images_per_s']:>10.2f}"
              f"{r['median_n_inliers']:>16.0f}")
    print(f"\nload average before/after: {load_before[0]:.2f} / {load_after[0]:.2f} on {os.cpu_count()} cores")
    write_json({"pairs": pair_rows, "compute_features": cf_rows, "image_size": [W, H],
                "load_average_1min": [load_before[0], load_after[0]], "cpu_count": os.cpu_count(),
                "python": platform.python_version(), "opencv": cv2.__version__, "git_commit": _git_commit()}, RESULTS)
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
