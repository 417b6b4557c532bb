"""Live closed-loop rate on an emulated GigE Vision camera: `expoctl drive --controller learned` (ONNX, 1 thread).

    sudo .venv/bin/python benchmarks/camera_loop.py [--model models/controller.pt | --input-sizes 64 224]
                                                    [--frames 300] [--fps 25 100]

For each camera frame rate: one `arv-fake-gv-camera-0.8` at 640×480 Mono8, and `expoctl drive` with the learned
controller on ONNX Runtime with one thread, for `--frames` frames, exactly as a user runs it (each frame converted to
RGB, run through the network, its settings commanded, and written as PNG). Reported from the sequence's own record
(sequence.yaml `drive`): the sustained loop rate, the controller's time per frame, camera frames dropped in transport
and frames skipped because a newer one had arrived (the loop always acts on the newest frame; a loop slower than the
camera skips frames rather than falling behind), and the actuation delay read back.

The network: `--model` if given (a trained checkpoint with its .onnx beside it); otherwise the architecture of
conf/model/default.yaml at each `--input-sizes` (64 = the default-scale network the pipeline trains and deploys;
224 = the paper's), images stored at 224×224 as ingest does, with untrained weights — the same computation per frame
as a trained network.

Isolation: the emulator and expoctl run in a private network namespace whose only interface is loopback (Aravis'
discovery broadcasts on every interface), so this needs root. Prints a table and writes
benchmarks/results/camera_loop.json. The machine is shared: numbers are indicative.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

import yaml  # noqa: E402

EMULATOR = "arv-fake-gv-camera-0.8"


def default_model(dest: Path, input_size: int) -> Path:
    """conf/model/default.yaml's architecture at `input_size`, untrained, saved the way `train` saves one (+ ONNX)."""
    import torch

    from expoctl.net.model import ExposureNet, ModelConfig
    from expoctl.net.checkpoint import CHECKPOINT_FORMAT, export_onnx

    d = yaml.safe_load((ROOT / "conf" / "model" / "default.yaml").read_text())
    cfg = ModelConfig.from_dict(dict(d, input_size=input_size))
    torch.manual_seed(0)
    model = ExposureNet(cfg).eval()
    ckpt = {"format": CHECKPOINT_FORMAT, "model_config": cfg.to_dict(), "state_dict": model.state_dict(),
            "store_hw": [224, 224], "input_hw": list(cfg.input_size)}
    dest.mkdir(parents=True, exist_ok=True)
    torch.save(ckpt, dest / "controller.pt")
    export_onnx(model, dest / "controller.onnx")
    return dest / "controller.pt"


def run_one(ns: str, model: Path, label: str, fps: float, frames: int, work: Path) -> dict:
    serial = f"BENCH{uuid.uuid4().hex[:6]}"
    emu = subprocess.Popen(["ip", "netns", "exec", ns, EMULATOR, "-i", "127.0.0.1", "-s", serial],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        time.sleep(0.5)
        out = work / f"seq_{label}_{fps:g}"
        cmd = ["ip", "netns", "exec", ns, sys.executable, "-m", "expoctl.cli", "drive", "--camera", serial,
               "--controller", "learned", "--model", str(model), "--model-backend", "onnx", "--frames", str(frames),
               "--out", str(out), "--width", "640", "--height", "480", "--pixel-format", "Mono8", "--fps", f"{fps:g}",
               "--gain-db-per-raw", "6"]
        t0 = time.perf_counter()
        res = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        wall = time.perf_counter() - t0
        if res.returncode != 0:
            raise SystemExit(f"expoctl drive failed at {fps:g} fps:\n{res.stderr}")
        drive = yaml.safe_load((out / "sequence.yaml").read_text())["drive"]
        return {"network": label, "camera_fps": fps, "frames": drive["frames"], "loop_hz": drive["loop_hz"],
                "controller_ms": drive["controller_ms"], "dropped": drive["dropped"],
                "skipped_stale": drive["skipped_stale"], "actuation_delay_frames": drive["actuation_delay_frames"],
                "settings_source": drive["settings_source"], "command_wall_s": round(wall, 2)}
    finally:
        emu.kill()
        emu.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, help="trained checkpoint (default: the default architecture, untrained)")
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--input-sizes", type=int, nargs="+", default=[64, 224],
                    help="network input sizes to build when no --model is given")
    ap.add_argument("--fps", type=float, nargs="+", default=[25.0, 100.0])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "camera_loop.json")
    args = ap.parse_args()
    if os.geteuid() != 0 or shutil.which(EMULATOR) is None:
        raise SystemExit(f"needs root (network namespace) and {EMULATOR} (apt-get install aravis-tools)")
    from bench_meta import run_metadata

    ns = f"expoctl-bench-{uuid.uuid4().hex[:6]}"
    subprocess.run(["ip", "netns", "add", ns], check=True)
    rows = []
    try:
        subprocess.run(["ip", "netns", "exec", ns, "ip", "link", "set", "lo", "up"], check=True)
        with tempfile.TemporaryDirectory() as tmp:
            models = ({"trained": args.model} if args.model else
                      {f"{n} px": default_model(Path(tmp) / f"net{n}", n) for n in args.input_sizes})
            for label, model in models.items():
                for fps in args.fps:
                    rows.append(run_one(ns, model, label.replace(" ", ""), fps, args.frames, Path(tmp)))
    finally:
        subprocess.run(["ip", "netns", "delete", ns], check=False)

    print(f"expoctl drive --controller learned (ONNX, 1 thread), emulated camera 640x480 Mono8, {args.frames} frames")
    print(f"{'network':>8} {'camera fps':>10} {'loop Hz':>8} {'ctrl ms med':>11} {'ctrl ms p95':>11} {'dropped':>7} "
          f"{'skipped':>7} {'delay (readback)':>16}")
    for r in rows:
        print(f"{r['network']:>8} {r['camera_fps']:>10g} {r['loop_hz']:>8.1f} {r['controller_ms']['median']:>11.2f} "
              f"{r['controller_ms']['p95']:>11.2f} {r['dropped']:>7d} {r['skipped_stale']:>7d} "
              f"{r['actuation_delay_frames']['median']!s:>16}")
    result = {"benchmark": "camera_loop",
              "model": str(args.model) if args.model else "conf/model/default.yaml architecture, untrained",
              "resolution": [640, 480], "pixel_format": "Mono8", "onnx_threads": 1, "rows": rows, **run_metadata()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = args.out.with_suffix(".json.tmp")
    tmp_out.write_text(json.dumps(result, indent=2) + "\n")
    os.replace(tmp_out, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
