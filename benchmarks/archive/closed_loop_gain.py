"""How much of the scene a trained network reads from the image, and the closed-loop offset that implies.

    .venv/bin/python benchmarks/archive/closed_loop_gain.py --data data/iter2 models/controller.pt models/controller_iter2.pt

The probe (expoctl.net.follow, which also gives train.json its val_follow) is open-loop, on the validation
split of a samples table: c111 and c222 share one label but differ in their input settings. follow 0 = the network
reads the scene from the image, 1 = it holds its input settings; bias = its median step from the reference camera's
state; offset = bias / (1 − follow), the linearised closed-loop fixed point above the reference.
Writes benchmarks/results/closed_loop_gain.json.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from expoctl.net.follow import MIN_INPUT_DIFFERENCE_EV, camera_follow
from expoctl.controllers.learned import LearnedController
from expoctl.net.dataset import load_sample_sets_from_files
from expoctl.io import write_json

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--data", type=Path, default=ROOT / "data",
                    help="directory holding samples.parquet, frames.parquet and images/ (e.g. data/iter2)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "archive" / "results" / "closed_loop_gain.json")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    rows = []
    for ckpt in args.checkpoints:
        ctrl = LearnedController.from_checkpoint(ckpt)
        sets = load_sample_sets_from_files(args.data / "samples.parquet", args.data / "frames.parquet",
                                           args.data / "images", ctrl.input_hw, splits=("validation",),
                                           exposure_scale=ctrl.exposure_scale)
        result = camera_follow(ctrl.model, sets["validation"])
        if result["n_time_steps"] == 0:
            raise SystemExit(f"closed_loop_gain: {args.data}/samples.parquet has no matching c111 / c222 pairs")
        rows.append({"checkpoint": str(ckpt), **result})
    print(f"validation split of {args.data} ({rows[0]['n_time_steps']} time steps, {rows[0]['n_used']} with "
          f"|Δ input| > {MIN_INPUT_DIFFERENCE_EV} EV)")
    print(f"{'network':34s} {'follow':>7s} {'bias':>8s} {'target':>8s} {'|err| c111':>11s} {'|err| c222':>11s} "
          f"{'offset = bias/(1-follow)':>25s}")
    for r in rows:
        print(f"{r['checkpoint']:34s} {r['follow']:7.2f} {r['bias_ev']:+7.2f}  {r['target_step_ev']:+7.2f}  "
              f"{r['abs_error_c111_ev']:10.2f}  {r['abs_error_c222_ev']:10.2f}  {r['implied_offset_ev']:+24.2f}")
    write_json({"data": str(args.data), "seconds": time.perf_counter() - t0, "networks": rows}, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
