"""What a trained network commands on a clipped frame: its step (EV) on an all-white and an all-black input, over a
grid of input settings.

    .venv/bin/python benchmarks/archive/white_step.py models/controller.pt [more.pt …] [--out FILE]

An all-white frame (every code 255, in all three input frames) says only "overexposed": the next setting must be
darker, whatever the settings planes say. A step ≥ 0 there means a white frame at those settings is an absorbing
state of the closed loop, which `benchmarks/archive/saturation_recovery.py` (the select_model probe) finds from a +6 EV start.
A black frame is the mirror image. Open loop, no simulator, a few milliseconds per network. The step is
output − input exposure product (exposure time and gain) in EV, with the output clamped to the network's range as the
deployed controller clamps it. Writes benchmarks/results/white_step.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from expoctl.io import write_json  # noqa: E402
from expoctl.net.checkpoint import load_checkpoint  # noqa: E402
from expoctl.net.clipped_frames import GRID_EXPOSURES_US, GRID_GAINS_DB, uniform_frame_steps  # noqa: E402

from bench_meta import run_metadata  # noqa: E402

GAINS_DB, EXPOSURES_US = GRID_GAINS_DB, GRID_EXPOSURES_US


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "archive" / "results" / "white_step.json")
    args = ap.parse_args()
    t0 = time.perf_counter()
    rows = {}
    for path in args.checkpoints:
        model, ckpt = load_checkpoint(path)
        scale = ckpt["model_config"].get("exposure_scale", "linear")
        hw = tuple(ckpt["input_hw"])
        white, black = (uniform_frame_steps(model, code, hw, scale).numpy() for code in (255, 0))
        rows[str(path)] = {"white_step_ev": white.round(3).tolist(), "black_step_ev": black.round(3).tolist(),
                           "white_max_step_ev": float(white.max()), "black_min_step_ev": float(black.min())}
        print(f"{path}: step on an all-white input (EV), rows gain dB, columns exposure µs")
        print("  gain \\ µs " + "".join(f"{e:>8.0f}" for e in EXPOSURES_US))
        for gdb, row in zip(GAINS_DB, white):
            print(f"  {gdb:9.0f} " + "".join(f"{v:+8.2f}" for v in row))
        print(f"  largest step on white {white.max():+.2f} EV (≥ 0: an absorbing white state), "
              f"smallest on black {black.min():+.2f} EV (≤ 0: an absorbing black state)")
    write_json({"gains_db": list(GAINS_DB), "exposures_us": list(EXPOSURES_US), "networks": rows,
                "seconds": round(time.perf_counter() - t0, 2), **run_metadata()}, args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
