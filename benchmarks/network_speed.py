"""Speed of the controller network at several input sizes: size, training throughput, single-frame inference.

    .venv/bin/python benchmarks/network_speed.py [--sizes 224 160 128 96] [--repeats 50] [--train-threads 2]

Per input size: parameters, multiply-adds per sample; training samples/s (forward + backward + Adam step, batch 64,
`--train-threads` torch threads); single-frame inference (batch 1, eval mode) on ONE CPU thread for torch and
ONNX Runtime — median latency and the rate it implies. Medians over `--repeats` timed calls after warm-up.
Prints a table and writes benchmarks/results/network_speed.json. The machine is shared: numbers are indicative.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from expoctl.net.model import ExposureNet, ModelConfig, count_macs, count_parameters
from expoctl.net.train import weighted_l1
from expoctl.net.checkpoint import export_onnx


def _median_seconds(fn, repeats: int, warmup: int = 3) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_size(size: int, repeats: int, train_threads: int, batch: int = 64) -> dict:
    import onnxruntime as ort

    cfg = ModelConfig(input_size=(size, size))
    torch.manual_seed(0)
    model = ExposureNet(cfg)
    out = {"input_size": size, "n_parameters": count_parameters(model), "macs_per_sample": count_macs(cfg)}

    torch.set_num_threads(train_threads)
    model.train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    x = torch.rand(batch, 15, size, size)
    y = torch.rand(batch, 2)

    def step():
        loss = weighted_l1(model(x), y, 0.5)
        opt.zero_grad()
        loss.backward()
        opt.step()

    t_step = _median_seconds(step, max(3, repeats // 10), warmup=2)
    out.update(train_threads=train_threads, train_batch=batch, train_samples_per_s=batch / t_step)

    torch.set_num_threads(1)
    model.eval()
    x1 = torch.rand(1, 15, size, size)
    with torch.no_grad():
        t_torch = _median_seconds(lambda: model(x1), repeats)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "m.onnx"
        export_onnx(model, path)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        sess = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        xn = x1.numpy()
        t_ort = _median_seconds(lambda: sess.run(None, {"input": xn}), repeats)
    out.update(torch_latency_ms=1e3 * t_torch, torch_rate_hz=1 / t_torch,
               onnxruntime_latency_ms=1e3 * t_ort, onnxruntime_rate_hz=1 / t_ort)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[224, 160, 128, 96])
    ap.add_argument("--repeats", type=int, default=50)
    ap.add_argument("--train-threads", type=int, default=2)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "network_speed.json"))
    args = ap.parse_args()
    rows = [bench_size(s, args.repeats, args.train_threads) for s in args.sizes]
    hdr = (f"{'size':>5} {'params':>10} {'GMACs':>7} {'train/s':>8} {'torch ms':>9} {'torch Hz':>9} "
           f"{'ORT ms':>7} {'ORT Hz':>7}")
    print(hdr)
    for r in rows:
        print(f"{r['input_size']:>5} {r['n_parameters']:>10,} {r['macs_per_sample'] / 1e9:>7.3f} "
              f"{r['train_samples_per_s']:>8.1f} {r['torch_latency_ms']:>9.2f} {r['torch_rate_hz']:>9.1f} "
              f"{r['onnxruntime_latency_ms']:>7.2f} {r['onnxruntime_rate_hz']:>7.1f}")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({
        "command": "benchmarks/network_speed.py " + " ".join(f"--{k.replace('_', '-')} {v}" for k, v in vars(args).items()
                                                           if k != "out"),
        "machine": {"cpu": platform.processor() or platform.machine(), "torch": torch.__version__,
                    "note": "2 cores shared with other jobs: indicative medians"},
        "results": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
