"""What training costs per sample-epoch at the default scale's 64 px input and at the paper's 224 px network (CPU).

    .venv/bin/python benchmarks/train_cost.py [--sizes 64 224] [--repeats 3] [--epochs 3] [--threads 2]

A small timed `fit` per input size on the synthetic set of `tests.support.synthetic_data` (a 224×224 image store, as
the pipeline's ingest writes; the cost per sample does not depend on what the images show): the network of
conf/model/default.yaml at that input size, the hyperparameters of conf/train/default.yaml (batch 64, the
clipped-frame prior on) on `--threads` torch threads, `--epochs` epochs, `--repeats` independent runs. Per size, the
median over the runs of each run's median over its epochs of:
  train s/sample   the training loop of one epoch (forward + backward + Adam step, the prior's extra forward) per
                   training sample (the history's `epoch_seconds`);
  val s/sample     the rest of the epoch (validation forward passes) per validation sample;
and the one-off load of the image store (decode + resize) per image. Every run's figures are kept in the JSON.
`--device cuda` times the same on a GPU host (`train.device`; measured here: CPU only). No GPU was measured. The machine is shared:
numbers are indicative (the 1-minute load average is recorded). Prints a table and writes
benchmarks/results/train_cost.json.
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

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # for tests.support.synthetic_data (test support code, not part of the library)
sys.path.insert(0, str(ROOT / "benchmarks"))

import torch  # noqa: E402

from bench_meta import run_metadata  # noqa: E402
from expoctl.net.dataset import load_sample_sets_from_files  # noqa: E402
from expoctl.net.model import ModelConfig, count_macs  # noqa: E402
from expoctl.net.train import TrainConfig, fit  # noqa: E402
from tests.support.synthetic_data import make_synthetic_dataset  # noqa: E402

STORE_HW = (224, 224)


def measure(size: int, paths: dict, epochs: int, threads: int, device: str = "cpu") -> dict:
    model_cfg = ModelConfig.from_dict({**yaml.safe_load((ROOT / "conf/model/default.yaml").read_text()),
                                       "input_size": size})
    train_cfg = TrainConfig.from_dict({**yaml.safe_load((ROOT / "conf/train/default.yaml").read_text()),
                                       "epochs": epochs, "patience": epochs, "num_threads": threads, "device": device})
    torch.set_num_threads(threads)
    t0 = time.perf_counter()
    sets = load_sample_sets_from_files(paths["samples"], paths["frames"], paths["images_dir"], size,
                                       exposure_scale=model_cfg.exposure_scale)
    load_s = time.perf_counter() - t0
    n_images = int(sets["train"].frames.shape[0])  # one cache of every stored image the splits use
    n_train, n_val = len(sets["train"]), len(sets["validation"])
    stamps = [time.perf_counter()]
    result = fit(model_cfg, train_cfg, sets["train"], sets["validation"], seed=0,
                 on_epoch=lambda e, m: stamps.append(time.perf_counter()))
    walls = [b - a for a, b in zip(stamps, stamps[1:])]
    trains = [h["epoch_seconds"] for h in result.history]
    return {"input_size": size, "macs_per_sample": count_macs(model_cfg), "threads": threads,
            "batch_size": train_cfg.batch_size, "clipped_frame_weight": train_cfg.clipped_frame_weight,
            "n_train_samples": n_train, "n_validation_samples": n_val, "epochs": len(trains),
            "train_s_per_sample_each_epoch": [t / n_train for t in trains],
            "val_s_per_sample_each_epoch": [(w - t) / n_val for w, t in zip(walls, trains)],
            "load_images": n_images, "load_s_per_image": load_s / max(n_images, 1),
            "load_average_1min_after": os.getloadavg()[0]}


def summarise(runs: list[dict]) -> dict:
    """One size's row: medians over runs of per-run medians over epochs; every run kept under `runs`."""
    med = statistics.median
    return {**{k: runs[0][k] for k in ("input_size", "macs_per_sample", "threads", "batch_size",
                                       "clipped_frame_weight", "n_train_samples", "n_validation_samples", "epochs")},
            "train_s_per_sample": med(med(r["train_s_per_sample_each_epoch"]) for r in runs),
            "val_s_per_sample": med(med(r["val_s_per_sample_each_epoch"]) for r in runs),
            "load_images": runs[0]["load_images"], "load_s_per_image": med(r["load_s_per_image"] for r in runs),
            "repeats": len(runs), "runs": runs}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[64, 224])
    ap.add_argument("--epochs", type=int, default=3, help="timed epochs per run (median over them)")
    ap.add_argument("--repeats", type=int, default=3, help="runs per size (median over them)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda", "auto"], help="train.device (cuda: a GPU host)")
    ap.add_argument("--n-sequences", type=int, default=6, help="synthetic sequences (4 train, 1 test, 1 validation)")
    ap.add_argument("--n-frames", type=int, default=14, help="frames per sequence (14: 384 training samples)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/train_cost.json")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        paths = make_synthetic_dataset(Path(tmp), n_sequences=args.n_sequences, n_frames=args.n_frames, hw=STORE_HW,
                                       seed=0)
        rows = [summarise([measure(size, paths, args.epochs, args.threads, args.device) for _ in range(args.repeats)])
                for size in args.sizes]
    print(f"{'input':>6} {'MACs/sample':>12} {'train s/sample':>15} {'val s/sample':>13} {'load s/image':>13} "
          f"{'n train':>8} {'n val':>6}")
    for r in rows:
        print(f"{r['input_size']:>4}px {r['macs_per_sample'] / 1e6:>10.1f}M {r['train_s_per_sample']:>15.4f} "
              f"{r['val_s_per_sample']:>13.4f} {r['load_s_per_image']:>13.5f} {r['n_train_samples']:>8} "
              f"{r['n_validation_samples']:>6}")
    out = {**run_metadata(), "torch": torch.__version__, "device": args.device, "store_hw": list(STORE_HW),
           "data": "synthetic (tests.support.synthetic_data), 224x224 store", "rows": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
