"""How bright camera 1 (the reference controller) ran in each data-collection iteration (not a test).

Iteration 2 collects with the iteration-1 network as camera 1's reference; if that network saturates, the new data is
mostly clipped reference frames. For each pipeline checkout this reads the last iteration's ingested store
(data/iter2/frames.parquet and images/) and prints, per iteration (traversals < 100: iteration 1, 100–199: 2) and
camera, the median share of pixels at or above SATURATED_DN, the share of frames more than half clipped, and the
median share of pixels at or below 5 DN (dark). Numbers from recorded images only: nothing here depends on the
closed-loop evaluation.

    .venv/bin/python benchmarks/archive/iteration_data.py NAME=RUN [NAME=RUN ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT / "src"))

from expoctl.camera.response import DARK_DN, SATURATED_DN  # noqa: E402


def iteration_of(sequence: str) -> int:
    return 1 + int(sequence.rsplit("-t", 1)[1]) // 100


def run_rows(name: str, root: Path) -> list[dict]:
    frames = pd.read_parquet(root / "data" / "iter2" / "frames.parquet")
    frames = frames[frames["split"] == "train"]
    stats = []
    for seq, f in frames.groupby("sequence"):
        store = np.load(root / "data" / "iter2" / "images" / f"{seq}.npy", mmap_mode="r")
        for cam, fc in f.groupby("camera"):
            imgs = np.asarray(store[fc["image_index"].to_numpy()])
            if imgs.ndim == 5:  # the store holds (frame, camera, h, w, channel)
                imgs = imgs[:, int(cam) - 1]
            flat = imgs.max(axis=-1).reshape(len(fc), -1)  # a pixel clips when any channel does
            clipped = (flat >= SATURATED_DN).mean(axis=1)
            dark = (flat <= DARK_DN).mean(axis=1)
            stats.append(pd.DataFrame({"iteration": iteration_of(seq), "camera": cam, "clipped": clipped,
                                       "dark": dark}))
    s = pd.concat(stats)
    return [{"run": name, "iteration": it, "camera": cam, "frames": len(g),
             "median_clipped": float(g["clipped"].median()), "half_clipped": float((g["clipped"] > 0.5).mean()),
             "median_dark": float(g["dark"].median())}
            for (it, cam), g in s.groupby(["iteration", "camera"])]


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if not args:
        print(__doc__, file=sys.stderr)
        return 2
    rows = []
    for spec in args:
        name, _, d = spec.partition("=")
        if not (Path(d) / "data" / "iter2" / "frames.parquet").is_file():
            print(f"iteration_data: {spec}: expected NAME=RUN with RUN/data/iter2/frames.parquet", file=sys.stderr)
            return 2
        rows += run_rows(name, Path(d))
    print("| run | iteration | camera | frames | median clipped share | frames > 50 % clipped | median dark share |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['run']} | {r['iteration']} | {r['camera']} | {r['frames']} | {r['median_clipped']:.1%} | "
              f"{r['half_clipped']:.1%} | {r['median_dark']:.1%} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
