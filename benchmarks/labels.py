"""Speed of the labels and samples stages' library code at paper scale (~100k frames).

Synthetic tables (random counts and settings; the numbers do not matter, the table sizes do): S sequences × F frames,
both cameras, one front end. Times compute_labels, compute_label_stats + render_markdown, and build_samples; prints
a table of medians over repeats and writes benchmarks/results/labels.json.

    .venv/bin/python benchmarks/labels.py [--sequences 55] [--frames 1820] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import numpy as np
import pandas as pd

from expoctl.labels.report import compute_label_stats, render_markdown
from expoctl.labels.targets import compute_labels
from expoctl.labels.samples import build_samples


def make_tables(n_seq: int, n_frames: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    seq = np.repeat([f"seq{k:03d}" for k in range(n_seq)], n_frames * 2)
    fid = np.tile(np.repeat(np.arange(n_frames), 2), n_seq)
    cam = np.tile([1, 2], n_seq * n_frames)
    n = len(seq)
    frames = pd.DataFrame({"sequence": seq, "frame_id": fid, "camera": cam, "gain_db": rng.uniform(0, 30, n),
                           "exposure_us": rng.uniform(75, 30000, n), "split": "train", "section": "static"})
    features = pd.DataFrame({"sequence": seq, "frame_id": fid, "camera": cam, "frontend": "orb",
                             "n_features": rng.integers(0, 2000, n)})
    keep = np.tile(np.arange(n_frames) < n_frames - 1, n_seq)
    mseq = np.repeat(np.repeat([f"seq{k:03d}" for k in range(n_seq)], n_frames)[keep], 4)
    mfid = np.repeat(np.tile(np.arange(n_frames), n_seq)[keep], 4)
    m = len(mseq)
    matches = pd.DataFrame({"sequence": mseq, "frame_id": mfid, "cam_from": np.tile([1, 1, 2, 2], m // 4),
                            "cam_to": np.tile([1, 2, 1, 2], m // 4), "frontend": "orb",
                            "n_matches": rng.integers(0, 1000, m), "n_inliers": rng.integers(0, 500, m)})
    return frames, features, matches


def timed(fn, repeats):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=55)
    ap.add_argument("--frames", type=int, default=1820)  # 55 × 1820 ≈ 100k frames (time steps), 200k images
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    frames, features, matches = make_tables(args.sequences, args.frames)
    t_labels, labels = timed(lambda: compute_labels(frames, features, matches), args.repeats)
    t_report, _ = timed(lambda: render_markdown(compute_label_stats(labels, frames)), args.repeats)
    t_samples, samples = timed(lambda: build_samples(frames, labels), args.repeats)
    n_steps = args.sequences * args.frames
    rows = [("compute_labels", t_labels, len(labels)), ("label report", t_report, len(labels)),
            ("build_samples", t_samples, len(samples))]
    print(f"{args.sequences} sequences × {args.frames} frames = {n_steps} time steps ({2 * n_steps} images), "
          f"median of {args.repeats}")
    print(f"{'step':<16}{'median s':>10}{'rows out':>12}{'time steps/s':>14}")
    for name, t, n in rows:
        print(f"{name:<16}{t:>10.2f}{n:>12}{n_steps / t:>14.0f}")
    result = {"sequences": args.sequences, "frames_per_sequence": args.frames, "time_steps": n_steps,
              "repeats": args.repeats, "machine": platform.processor() or platform.machine(),
              "median_seconds": {name: t for name, t, _ in rows}, "rows_out": {name: n for name, _, n in rows}}
    out = Path(__file__).resolve().parent / "results" / "labels.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
