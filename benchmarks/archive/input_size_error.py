"""What a smaller network input costs in validation error, against the paper's 224×224, on a training subset.

    .venv/bin/python benchmarks/archive/input_size_error.py                      # pipeline data if present, else synthetic
    .venv/bin/python benchmarks/archive/input_size_error.py --samples data/samples.parquet --frames data/frames.parquet \
        --images-dir data/images --sizes 224 128 96 --max-train 2000 --epochs 10

The same subset, seed and hyperparameters at every size; only `model.input_size` changes (images are resized from
the store by the shared preprocessing, the 4th conv's kernel is computed). Without pipeline data it generates the
synthetic set of `tests.support.synthetic_data` at 224×224 (say so when quoting the numbers). Writes
benchmarks/results/input_size_error.json.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT))  # for tests.support.synthetic_data (test support code, not part of the library)

from expoctl.net.dataset import load_sample_sets_from_files  # noqa: E402
from expoctl.net.model import ModelConfig  # noqa: E402
from expoctl.net.train import TrainConfig, fit  # noqa: E402
from tests.support.synthetic_data import make_synthetic_dataset  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", default=str(ROOT / "data" / "samples.parquet"))
    ap.add_argument("--frames", default=str(ROOT / "data" / "frames.parquet"))
    ap.add_argument("--images-dir", default=str(ROOT / "data" / "images"))
    ap.add_argument("--sizes", type=int, nargs="+", default=[224, 128, 96, 64])
    ap.add_argument("--max-train", type=int, default=640)
    ap.add_argument("--max-val", type=int, default=320)
    ap.add_argument("--epochs", type=int, default=6)
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--exposure-scale", choices=["linear", "log"], default="log")
    ap.add_argument("--output", choices=["absolute", "residual"], default="residual")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "archive" / "results" / "input_size_error.json"))
    args = ap.parse_args()

    tmp = None
    source = "pipeline"
    if not Path(args.samples).exists():
        tmp = tempfile.TemporaryDirectory()
        paths = make_synthetic_dataset(tmp.name, n_sequences=8, n_frames=40, hw=(224, 224), seed=args.seed)
        args.samples, args.frames, args.images_dir = paths["samples"], paths["frames"], paths["images_dir"]
        source = "synthetic (tests.support.synthetic_data, 8 sequences × 40 frames, 224×224 store)"
    cfg = TrainConfig(lr=args.lr, batch_size=args.batch_size, epochs=args.epochs, patience=args.epochs,
                      num_threads=args.threads, max_train_samples=args.max_train, max_validation_samples=args.max_val)
    rows = []
    for size in args.sizes:
        sets = load_sample_sets_from_files(args.samples, args.frames, args.images_dir, size,
                                           exposure_scale=args.exposure_scale)
        t0 = time.perf_counter()
        model_cfg = ModelConfig(input_size=(size, size), exposure_scale=args.exposure_scale, output=args.output)
        r = fit(model_cfg, cfg, sets["train"], sets["validation"], args.seed,
                log=lambda s, size=size: print(f"[{size}] {s}", flush=True))
        m = r.metrics
        rows.append({"input_size": size, "train_seconds": time.perf_counter() - t0,
                     **{k: m[k] for k in ("val_loss", "val_gain_mae_db", "val_exposure_mae_ev", "baseline_val_loss",
                                          "baseline_val_gain_mae_db", "baseline_val_exposure_mae_ev", "best_epoch",
                                          "n_train_samples", "n_validation_samples", "train_samples_per_s",
                                          "macs_per_sample", "n_parameters")}})
    ref = next((r for r in rows if r["input_size"] == 224), rows[0])
    print(f"data: {source}")
    print(f"{'size':>5} {'val loss':>9} {'Δ vs ref':>9} {'gain dB':>8} {'exp EV':>7} {'train s':>8} {'smp/s':>6}")
    for r in rows:
        r["val_loss_increase_vs_ref"] = r["val_loss"] - ref["val_loss"]
        print(f"{r['input_size']:>5} {r['val_loss']:>9.4f} {r['val_loss_increase_vs_ref']:>+9.4f} "
              f"{r['val_gain_mae_db']:>8.2f} {r['val_exposure_mae_ev']:>7.3f} {r['train_seconds']:>8.0f} "
              f"{r['train_samples_per_s']:>6.1f}")
    print(f"constant predictor: loss {ref['baseline_val_loss']:.4f}, gain {ref['baseline_val_gain_mae_db']:.2f} dB, "
          f"exposure {ref['baseline_val_exposure_mae_ev']:.3f} EV")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"data": source, "reference_size": ref["input_size"],
                                          "settings": {k: v for k, v in vars(args).items() if k != "out"},
                                          "results": rows}, indent=2, default=str) + "\n")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()
