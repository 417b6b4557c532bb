"""AG+AE model vs the authors' recordings: per-frame change of the exposure product on camera 1 (not a test).

docs/controllers.md gives the statistics of the real Blackfly S AG+AE in Tomasi et al.'s recordings: the exposure
product t·gain changed by a median 0.015–0.033 EV per frame, p99 0.16–0.29 EV, at most ~0.5 EV. This reads the raw
sequences a `collect` run wrote (camera 1 = the reference controller, AG+AE in iteration 1) and prints the same
statistics per sequence and over all, so the simulated loop's speed can be checked against the real camera's.

    .venv/bin/python benchmarks/archive/agae_calibration.py [RAW_DIR]    (default: data/raw)

Prints a table and writes benchmarks/results/agae_calibration.json.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT / "src"))

from expoctl.errors import InputError  # noqa: E402
from expoctl.io import write_json  # noqa: E402
from expoctl.raw.format import find_sequences, read_frames_csv  # noqa: E402

AUTHORS = {"median": (0.015, 0.033), "p99": (0.16, 0.29), "max": 0.5}
EV_PER_DB = 1.0 / (20.0 * np.log10(2.0))


def step_stats(steps: np.ndarray) -> dict:
    return {"frames": int(steps.size), "median": float(np.median(steps)), "p90": float(np.percentile(steps, 90)),
            "p99": float(np.percentile(steps, 99)), "max": float(steps.max())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("raw_dir", nargs="?", type=Path, default=ROOT / "data" / "raw")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "archive" / "results" / "agae_calibration.json")
    args = ap.parse_args()
    per_seq, all_steps = {}, []
    try:
        seq_dirs = find_sequences(args.raw_dir)
        for seq_dir in seq_dirs:
            frames = read_frames_csv(seq_dir)
            try:
                num = frames[["frame_id", "camera", "gain_db", "exposure_us"]].apply(pd.to_numeric)
            except (KeyError, ValueError) as exc:
                raise InputError(f"{seq_dir / 'frames.csv'}: {exc} (check it with `expoctl validate`)") from None
            cam1 = num[num["camera"] == 1].sort_values("frame_id")
            ev = np.log2(cam1["exposure_us"].to_numpy(float)) + cam1["gain_db"].to_numpy(float) * EV_PER_DB
            steps = np.abs(np.diff(ev))[np.diff(cam1["frame_id"].to_numpy()) == 1]  # consecutive frames only
            if steps.size:
                per_seq[seq_dir.name] = step_stats(steps)
                all_steps.append(steps)
    except InputError as exc:
        print(f"agae_calibration: {exc}", file=sys.stderr)
        return 2
    if not all_steps:
        print(f"agae_calibration: no consecutive camera-1 frames under {args.raw_dir}", file=sys.stderr)
        return 2
    total = step_stats(np.concatenate(all_steps))
    print(f"camera 1 |Δ log2(t·gain)| per frame (EV), {len(per_seq)} sequences under {args.raw_dir}")
    print(f"{'sequence':32s} {'frames':>6} {'median':>7} {'p90':>6} {'p99':>6} {'max':>6}")
    for name, s in list(per_seq.items()) + [("all", total)]:
        print(f"{name:32s} {s['frames']:6d} {s['median']:7.3f} {s['p90']:6.3f} {s['p99']:6.3f} {s['max']:6.3f}")
    print(f"{'authors (Blackfly S AG+AE)':32s} {'':6s} {'0.015–0.033':>7s} {'':6s} {'0.16–0.29':>6s} {'~0.5':>6s}")
    write_json({"raw_dir": str(args.raw_dir), "per_sequence": per_seq, "all": total, "authors": AUTHORS}, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
