"""Cost of closed-loop evaluation runs (render + sensor + controller + ORB/libviso2 raw & SumLog + VO) per frame.

Runs a few controllers over the first `--frames` frames of the validation city's first evaluation window at each
`--sizes` render size, with the repository's default configs, and reports wall and CPU seconds per frame (medians
over controllers where it says so). CPU time is what matters for the pipeline budget on a shared machine.

    .venv/bin/python benchmarks/evaluate_speed.py --sizes 320x240 640x480 --frames 30
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_meta import default_config  # noqa: E402


def cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", nargs="+", default=["320x240", "640x480"])
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--controllers", nargs="+", default=["agae", "shin", "oracle"])
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/evaluate_speed.json"))
    args = ap.parse_args()

    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.evaluation.runner import RunJob, plan_windows, run_window
    from expoctl.features.sumlog import SumLogParams

    rows = []
    for size in args.sizes:
        w, h = (int(v) for v in size.split("x"))
        cfg = default_config([f"evaluate.render_size=[{w},{h}]"])
        inputs = EvaluationInputs.from_resolved(cfg)
        windows = plan_windows(inputs, ROOT)
        win = dataclasses.replace(windows[0], stop=windows[0].start + args.frames)
        sumlog = {"orb": SumLogParams(beta=8.0), "viso": SumLogParams(beta=8.0)}
        run_window((RunJob(dataclasses.replace(win, stop=win.start + 3), "fixed", inputs, sumlog),))  # warm caches / JIT
        for ctrl in args.controllers:
            t0, c0 = time.perf_counter(), cpu_s()
            _, summary, _ = run_window((RunJob(win, ctrl, inputs, sumlog, str(ROOT / "models/controller.pt")),))[0]
            wall, cpu = time.perf_counter() - t0, cpu_s() - c0
            n = summary["n_frames"] + summary["warmup_frames"]
            rows.append({"size": size, "controller": ctrl, "frames_incl_warmup": n, "wall_s_per_frame": wall / n,
                         "cpu_s_per_frame": cpu / n, "oracle_ms_median": summary.get("oracle_ms_median")})
            print(f"{size:>8} {ctrl:>15}: {wall / n:6.3f} s wall/frame, {cpu / n:6.3f} s CPU/frame "
                  f"({n} frames incl. warm-up)" + (f", oracle decision {summary['oracle_ms_median']:.0f} ms median"
                                                  if ctrl == "oracle" else ""), flush=True)
    out = {"rows": rows, "load_average_1min": os.getloadavg()[0], "cpu_count": os.cpu_count(),
           "note": "per frame = render + sensor + controller + ORB & libviso2-style (raw + SumLog) + VO ORB"}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print("→", args.out)


if __name__ == "__main__":
    main()
