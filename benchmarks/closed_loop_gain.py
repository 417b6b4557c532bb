"""How much of the scene a trained network reads from the image, and the closed-loop offset that implies.

    .venv/bin/python benchmarks/closed_loop_gain.py --data data/iter2 models/controller.pt models/controller_iter2.pt

The probe is open-loop, on the validation split of a samples table. At each labelled time step the samples c111 and
c222 share one label (the best settings for frame t+1 do not depend on which camera's frames the network looks at),
but their inputs differ: camera 2's settings are perturbed, and its images are correspondingly brighter or darker.
A network that reads the scene from the image gives both the same output; one that holds its input settings moves
its output with them. Per network:

  follow   slope of (output EV, c222 − c111) on (input EV at t, c222 − c111), time steps with |Δ input| > 0.2 EV:
           0 = reads the scene, 1 = holds the settings (an untrained residual network)
  bias     median (output − input) EV of the c111 samples: the step it takes from the reference camera's state
  target   median (label − input) EV of the same samples: the step the labels ask for

In closed loop the network's input is its own last output. Linearised around the reference camera's state s_ref,
output(s) ≈ s_ref + bias + follow · (s − s_ref), whose fixed point lies offset = bias / (1 − follow) EV above s_ref:
a small per-frame bias is amplified when the network mostly follows its own settings. EV = log2(exposure) + gain/6.02.
Writes benchmarks/results/closed_loop_gain.json.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from expoctl.camera.ranges import exposure_value_ev, norm_to_exposure, norm_to_gain
from expoctl.controllers.learned import LearnedController
from expoctl.dataset import load_sample_sets_from_files
from expoctl.io import write_json

ROOT = Path(__file__).resolve().parents[1]
MIN_INPUT_DIFFERENCE_EV = 0.2  # time steps where the two cameras' settings differ less carry no slope information


def settings_ev(gain_norm: np.ndarray, exposure_norm: np.ndarray, exposure_scale: str) -> np.ndarray:
    return exposure_value_ev(norm_to_gain(gain_norm), norm_to_exposure(exposure_norm, exposure_scale))


def probe(samples, ctrl: LearnedController, checkpoint: Path, batch_size: int = 256) -> dict:
    ids = samples.sample_id
    stem = np.array([s.rsplit("/", 1)[0] for s in ids])
    combo = np.array([s.rsplit("/", 1)[1] for s in ids])
    i1, i2 = np.flatnonzero(combo == "c111"), np.flatnonzero(combo == "c222")
    if len(i1) == 0 or not np.array_equal(stem[i1], stem[i2]):
        raise SystemExit("closed_loop_gain: the samples table has no matching c111 / c222 pairs")

    def output_ev(idx: np.ndarray) -> np.ndarray:
        out = []
        with torch.no_grad():
            for j in range(0, len(idx), batch_size):
                x, _ = samples.batch(idx[j:j + batch_size])
                out.append(ctrl.model(x).numpy())
        o = np.concatenate(out)
        return settings_ev(o[:, 0], o[:, 1], samples.exposure_scale)

    def input_ev(idx: np.ndarray) -> np.ndarray:
        return settings_ev(samples.gain_norm[idx, 0].numpy(), samples.exposure_norm[idx, 0].numpy(),
                           samples.exposure_scale)

    target = settings_ev(samples.targets[i1, 0].numpy(), samples.targets[i1, 1].numpy(), samples.exposure_scale)
    out1, out2, in1, in2 = output_ev(i1), output_ev(i2), input_ev(i1), input_ev(i2)
    d_in, d_out = in2 - in1, out2 - out1
    use = np.abs(d_in) > MIN_INPUT_DIFFERENCE_EV
    follow = float(np.polyfit(d_in[use], d_out[use], 1)[0])
    bias = float(np.median(out1 - in1))
    return {"checkpoint": str(checkpoint), "n_time_steps": int(len(i1)), "n_used": int(use.sum()),
            "follow": follow, "bias_ev": bias, "target_step_ev": float(np.median(target - in1)),
            "abs_error_c111_ev": float(np.median(np.abs(out1 - target))),
            "abs_error_c222_ev": float(np.median(np.abs(out2 - target))),
            "implied_offset_ev": bias / (1.0 - follow) if follow < 1.0 else float("inf")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--data", type=Path, default=ROOT / "data",
                    help="directory holding samples.parquet, frames.parquet and images/ (e.g. data/iter2)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "closed_loop_gain.json")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    rows = []
    for ckpt in args.checkpoints:
        ctrl = LearnedController.from_checkpoint(ckpt)
        sets = load_sample_sets_from_files(args.data / "samples.parquet", args.data / "frames.parquet",
                                           args.data / "images", ctrl.input_hw, splits=("validation",),
                                           exposure_scale=ctrl.exposure_scale)
        rows.append(probe(sets["validation"], ctrl, ckpt))
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
