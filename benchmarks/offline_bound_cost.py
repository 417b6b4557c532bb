"""Cost of the offline bound (`evaluate.offline_bound`, expoctl.evaluation.offline_bound) per frame, beside one
AG+AE closed-loop run over the same frames, and what it would add to the default evaluate.

For each `--sizes` render size: the first `--frames` frames of the validation city's first evaluation window with
the repository's default configs, every frame's pair counted (`kinds=None`: the cost of a frame does not depend on
its label, and a short prefix may hold no dynamic frame). The bound renders one luminance per distinct exposure of
the grid, captures K images, extracts K feature sets per front end and matches K² pairs per front end; its wall and
CPU seconds per frame are split into those three parts (WindowBound.timings). The AG+AE run is evaluate's
`run_window` on the same frames (render, sensor, controller, ORB and libviso2-style raw and SumLog, VO).

The extrapolation multiplies the per-frame cost by the frames the default evaluate bounds: every frame of a static
or dynamic section (interior sections are not bounded) of every evaluation window, counted from the windows'
labels. Run it with one numba and OpenMP thread, as evaluate's workers run (the figures in benchmarks/README.md):

    NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 .venv/bin/python benchmarks/offline_bound_cost.py --sizes 160x120 640x480 --frames 8
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


def bounded_frames(inputs, windows) -> int:
    """Frames whose pair the default evaluate's bound computes: those in static or dynamic sections."""
    from expoctl.evaluation.offline_bound import window_sections
    from expoctl.evaluation.runner import window_sim

    total = 0
    for w in windows:
        labels = list(window_sim(inputs, w).frames.section)
        total += sum(len(s["pairs"]) for s in window_sections(labels, inputs.evaluate.min_section_frames)
                     if s["kind"] in ("static", "dynamic"))
    return total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", default=["160x120", "640x480"])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/offline_bound_cost.json"))
    args = ap.parse_args()

    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.evaluation.offline_bound import grid_label, offline_bound
    from expoctl.evaluation.runner import RunJob, plan_windows, run_window, window_sim
    from expoctl.features.pipeline import make_frontend
    from expoctl.features.sumlog import SumLogParams

    rows = []
    for size in args.sizes:
        w, h = (int(v) for v in size.split("x"))
        cfg = default_config([f"evaluate.render_size=[{w},{h}]"])
        inputs = EvaluationInputs.from_resolved(cfg)
        windows = plan_windows(inputs, ROOT)
        win = dataclasses.replace(windows[0], stop=windows[0].start + args.frames)
        candidates = inputs.evaluate.offline_bound.candidates(inputs.controller_config("oracle"))
        frontends = {n: make_frontend(n, inputs.features.config(n)) for n in inputs.evaluate.frontends}
        sumlog = {"orb": SumLogParams(beta=8.0), "viso": SumLogParams(beta=8.0)}
        run_window((RunJob(dataclasses.replace(win, stop=win.start + 3), "fixed", inputs, sumlog),))  # JIT, caches

        t0, c0 = time.perf_counter(), cpu_s()
        _, summary, _ = run_window((RunJob(win, "agae", inputs, sumlog),))[0]
        agae_n = summary["n_frames"] + summary["warmup_frames"]
        agae_wall, agae_cpu = (time.perf_counter() - t0) / agae_n, (cpu_s() - c0) / agae_n

        sim = window_sim(inputs, win)
        t0, c0 = time.perf_counter(), cpu_s()
        wb = offline_bound(sim.scene, sim.sensor, sim.frames, win.seed, frontends, candidates=candidates,
                           min_section_frames=1, kinds=None)
        pairs = sum(s["n_pairs"] for s in wb.sections)
        bound_wall, bound_cpu = (time.perf_counter() - t0) / pairs, (cpu_s() - c0) / pairs
        n_bounded = bounded_frames(inputs, windows)
        row = {"size": size, "grid": grid_label(candidates), "candidates": len(candidates),
               "distinct_exposures": len({c.exposure_us for c in candidates}), "frontends": list(frontends),
               "frames_timed": pairs, "bound_wall_s_per_frame": bound_wall, "bound_cpu_s_per_frame": bound_cpu,
               "bound_parts_s_per_frame": {k: v / pairs for k, v in wb.timings.items()},
               "agae_frames_timed": agae_n, "agae_wall_s_per_frame": agae_wall, "agae_cpu_s_per_frame": agae_cpu,
               "bound_over_agae_run": bound_wall / agae_wall, "default_evaluate_bounded_frames": n_bounded,
               "default_evaluate_bound_cpu_min": n_bounded * bound_cpu / 60.0}
        rows.append(row)
        parts = ", ".join(f"{k} {v:.3f}" for k, v in row["bound_parts_s_per_frame"].items())
        print(f"{size:>8}: bound {bound_wall:7.3f} s/frame ({parts}); AG+AE run {agae_wall:6.3f} s/frame; "
              f"ratio {bound_wall / agae_wall:5.1f}x; default evaluate: {n_bounded} frames -> "
              f"{row['default_evaluate_bound_cpu_min']:.0f} CPU-min", flush=True)
    out = {"rows": rows, "load_average_1min": os.getloadavg()[0], "cpu_count": os.cpu_count(),
           "threads": os.environ.get("NUMBA_NUM_THREADS"),
           "note": "bound per frame = renders (one per distinct exposure) + K captures + K extractions and K^2 "
                   "matches per front end (no SumLog variants, the default); AG+AE = evaluate's run_window per frame"}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(args.out).with_suffix(".json.tmp")
    tmp.write_text(json.dumps(out, indent=2) + "\n")
    tmp.replace(args.out)
    print("->", args.out)


if __name__ == "__main__":
    main()
