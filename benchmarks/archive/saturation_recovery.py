"""Does a learned controller recover from a badly exposed start? A closed-loop probe of its fixed points.

    .venv/bin/python benchmarks/archive/saturation_recovery.py models/controller.pt models/controller_iter2.pt

Open-loop metrics (validation loss, `closed_loop_gain.py`'s follow) describe a network in the states its training
data contain: camera 1 under a well-exposed reference, camera 2 within about ±1 EV of it. In closed loop the network
also meets states its data never contain, and the worst of them is a saturated frame: it shows almost nothing of the
scene, so nothing in the image tells the network how far to step down. If its step there is about zero, saturation
is an absorbing state and the controller stays white.

The probe itself is `expoctl.selection.saturation_probe` (the select_model stage runs the same probe on every candidate;
the protocol is in that module's docstring): train city, traversal 900 (no stage collects or evaluates it), 320×240, the
project's conf/ defaults for world, rig, sensor and AG+AE. This script runs it for any checkpoints over a wider set of
offsets, prints the table and writes benchmarks/results/saturation_recovery.json.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT / "src"))

from expoctl.controllers.learned import LearnedController  # noqa: E402
from expoctl.io import write_json  # noqa: E402
from expoctl.evaluation.inputs import EvaluationInputs  # noqa: E402
from expoctl.selection.saturation_probe import ProbeConfig, make_probe, verdict  # noqa: E402
from bench_meta import run_metadata  # noqa: E402


def _conf() -> dict:
    """conf/ defaults as the stages see them (only the groups the probe reads; ${sensor.*} resolved by compose)."""
    sys.path.insert(0, str(ROOT))
    from stages.compose import compose_config

    return compose_config([])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoints", nargs="+", type=Path)
    ap.add_argument("--offsets", type=float, nargs="+", default=[-4.0, -2.0, 0.0, 2.0, 4.0, 6.0], help="EV")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "archive" / "results" / "saturation_recovery.json")
    args = ap.parse_args()
    for ckpt in args.checkpoints:
        if not ckpt.is_file():
            raise SystemExit(f"saturation_recovery: no checkpoint {ckpt}")
    pcfg = ProbeConfig.from_dict({"city": "train", "traversal": 900, "seed": args.seed, "frames": args.frames,
                                  "offsets_ev": args.offsets, "width": args.width, "height": args.height}, "probe")
    t0 = time.perf_counter()
    inputs = EvaluationInputs.from_resolved(_conf())
    probe = make_probe(pcfg, inputs.world, inputs.rig, inputs.sensor, inputs.controller_params("agae"), ROOT)
    print(f"train city, traversal {pcfg.traversal}, {pcfg.width}×{pcfg.height}, {pcfg.frames} frames per run")
    for name, st in probe.starts.items():
        print(f"  {name} (frame {st['frame']}): starts at " + ", ".join(f"{a:+.1f}" for a in st["start_offsets_ev"])
              + " EV from AG+AE")
    print(f"{'network':34s} {'start':9s} " + " ".join(f"{'k=' + format(k, '+g'):>16s}" for k in args.offsets))
    print(f"{'':34s} {'':9s} " + " ".join(f"{'final / step / sat':>16s}" for _ in args.offsets))
    networks = {}
    for ckpt in args.checkpoints:
        result = probe.run(LearnedController.from_checkpoint(ckpt))
        for name, rows in result["starts"].items():
            cells = [f"{r['final_offset_ev']:+5.1f}/{r['mean_step_first_ev']:+5.2f}/{r['final_saturated_frac']:4.2f}"
                     for r in rows]
            print(f"{str(ckpt):34s} {name:9s} " + " ".join(f"{c:>16s}" for c in cells))
        dark_line = "off" if pcfg.max_dark_fraction is None else f"{pcfg.max_dark_fraction:.2f}"
        print(f"{'':34s} worst clipped share {result['worst_saturated_frac']:.2f} "
              f"(select_model's line {pcfg.max_saturated_fraction:.2f}), worst black share "
              f"{result['worst_dark_frac']:.2f} (line {dark_line}): {verdict(result)}")
        networks[str(ckpt)] = {**result["starts"], "worst_saturated_frac": result["worst_saturated_frac"],
                               "worst_dark_frac": result["worst_dark_frac"], "fails_on": result["fails_on"],
                               "passes": result["passes"]}
    seconds = time.perf_counter() - t0
    print(f"(final = offset from AG+AE's level over the last {pcfg.last_frames} frames, EV; step = mean EV per frame "
          f"over the first {pcfg.first_frames}; sat = clipped share of the last frame) {seconds:.0f} s")
    write_json({"city": pcfg.city, "traversal": pcfg.traversal, "size": [pcfg.width, pcfg.height],
                "frames": pcfg.frames, "offsets_ev": list(pcfg.offsets_ev), "starts": probe.starts,
                "networks": networks, "max_saturated_fraction": pcfg.max_saturated_fraction,
                "seconds": round(seconds, 1), **run_metadata()}, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
