"""What `evaluate.share_render: true` does to the images alone, with the controllers' decisions held fixed.

A closed loop amplifies any change of the image into different settings a few frames later, so comparing the two
render modes closed-loop mixes the render's effect with each controller's sensitivity to it. Here each controller
first drives the window closed-loop with `share_render: false` (its commands recorded); then the same command
sequences are replayed open-loop with `share_render: true` and with `false` again (the control: it must reproduce
the closed-loop rows exactly). Every frame is then captured at identical settings, pose and noise in both modes, and
the per-frame-pair NFM differences (true − false) measure the render's own effect.

Window and config: those of benchmarks/archive/evaluate_render_once.py (test city tunnel-0 exit, 640×480, ±2 s, 30 warm-up
frames), for each of --seeds (each its own traversal, sun, sky and noise). Printed and written (--out): per
controller and front end, the mean and median per-pair ΔNFM, its standard error over pairs, and the fraction of
pairs that changed; per seed, the median |Δ mean grey|.

    .venv/bin/python benchmarks/archive/render_once_replay.py --seeds 1 2 3
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path[:0] = [str(ROOT / "src"), str(ROOT), str(ROOT / "benchmarks")]


def drive(inputs, project: Path, controllers: list[str], replay: dict | None) -> tuple[dict, dict]:
    """One window, `controllers` in lockstep; with `replay` ({name: [Settings, ...]}) each controller is replaced by
    the playback of its recorded commands. Returns ({name: per-frame rows}, {name: the commands it issued})."""
    import expoctl.evaluation.run as run_mod
    from expoctl.controllers.base import Controller, TimedController
    from expoctl.evaluation.runner import RunJob, plan_windows, run_window, tune_sumlog_params

    issued: dict[str, list] = {}

    class Playback(Controller):
        def __init__(self, name, commands):
            self.name, self.commands, self.i = name, commands, 0

        def reset(self, initial):
            self.i = 0

        def update(self, image, applied):
            self.i += 1
            return self.commands[self.i - 1]

    class Recording(TimedController):
        def __init__(self, inner):
            if replay is not None:
                inner = Playback(inner.name, replay[inner.name])
            super().__init__(inner)
            issued[inner.name] = self.commands = []

        def update(self, image, applied):
            s = super().update(image, applied)
            self.commands.append(s)
            return s

    saved = run_mod.TimedController
    run_mod.TimedController = Recording
    try:
        (window,) = plan_windows(inputs, project)
        sumlog = tune_sumlog_params(inputs, project, inputs.evaluate.sumlog_pairs)
        model = str(inputs.learned_model_path(project))
        results = run_window(tuple(RunJob(window, c, inputs, sumlog, model) for c in controllers))
    finally:
        run_mod.TimedController = saved
    return {c: rows for c, (rows, _, _) in zip(controllers, results)}, issued


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--controllers", nargs="+", default=["agae", "shin", "shim", "mean_intensity", "learned"])
    ap.add_argument("--before-s", type=float, default=2.0)
    ap.add_argument("--after-s", type=float, default=2.0)
    ap.add_argument("--warmup", type=int, default=30)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/archive/results/render_once_replay.json"))
    args = ap.parse_args()

    import numpy as np
    import pandas as pd

    from bench_meta import run_metadata
    from evaluate_render_once import bench_config
    from expoctl.evaluation.inputs import EvaluationInputs

    pairs, grey = [], []
    with tempfile.TemporaryDirectory(prefix="render-once-replay-") as tmp:
        project = Path(tmp) / "project"
        base = bench_config(project, args)
        for seed in args.seeds:
            frames = {}
            for label, share, replay_of in (("closed false", False, None), ("replay true", True, "closed false"),
                                            ("replay false", False, "closed false")):
                cfg = json.loads(json.dumps(base))
                cfg["seed"], cfg["evaluate"]["share_render"] = seed, share
                cfg["evaluate"]["controllers"] = list(args.controllers)
                inputs = EvaluationInputs.from_resolved(cfg)
                rows, issued = drive(inputs, project, args.controllers, None if replay_of is None else frames[replay_of][1])
                frames[label] = ({c: pd.DataFrame(r) for c, r in rows.items()}, issued)
            for c in args.controllers:
                ref, rep, ctl = (frames[k][0][c] for k in ("closed false", "replay true", "replay false"))
                same = [k for k in ref.columns if k not in ("controller_ms",)]
                if not ref[same].equals(ctl[same]):
                    raise SystemExit(f"seed {seed} {c}: replaying with share_render false did not reproduce the "
                                     "closed loop — the playback is not exact")
                if not (np.array_equal(ref.exposure_us, rep.exposure_us) and np.array_equal(ref.gain_db, rep.gain_db)):
                    raise SystemExit(f"seed {seed} {c}: replayed settings differ from the recorded ones")
                grey.append({"seed": seed, "controller": c,
                             "median_abs_mean_grey_diff": float(np.median(np.abs(rep.mean_grey - ref.mean_grey)))})
                for fe in ("orb", "viso"):
                    d = (rep[f"nfm_{fe}"] - ref[f"nfm_{fe}"]).dropna().to_numpy()
                    pairs.extend({"seed": seed, "controller": c, "frontend": fe, "nfm_false": float(a),
                                  "delta": float(x)} for a, x in zip(ref[f"nfm_{fe}"].dropna(), d))
            print(f"seed {seed} done", flush=True)
    d = pd.DataFrame(pairs)
    summary = []
    print(f"\n| controller | front end | pairs | mean NFM (false) | mean Δ (true − false) | SE | median Δ | "
          "pairs changed |")
    print("|---|---|---|---|---|---|---|---|")
    for (c, fe), g in d.groupby(["controller", "frontend"], sort=False):
        x = g.delta.to_numpy()
        row = {"controller": c, "frontend": fe, "n_pairs": int(len(x)), "mean_nfm_false": float(g.nfm_false.mean()),
               "mean_delta": float(x.mean()), "se": float(x.std(ddof=1) / np.sqrt(len(x))),
               "median_delta": float(np.median(x)), "frac_changed": float(np.mean(x != 0))}
        summary.append(row)
        print(f"| {c} | {fe} | {row['n_pairs']} | {row['mean_nfm_false']:.1f} | {row['mean_delta']:+.1f} | "
              f"{row['se']:.1f} | {row['median_delta']:+.1f} | {row['frac_changed']:.0%} |")
    x = d.delta.to_numpy()
    rel = d.delta.sum() / d.nfm_false.sum()
    print(f"\nall: {len(x)} pairs, mean Δ {x.mean():+.2f} ± {x.std(ddof=1) / np.sqrt(len(x)):.2f} NFM "
          f"({rel:+.1%} of the mean NFM); median |Δ mean grey| per run "
          f"{np.median([g['median_abs_mean_grey_diff'] for g in grey]):.3f} DN")
    out = {"summary": summary, "overall": {"n_pairs": int(len(x)), "mean_delta": float(x.mean()),
                                           "se": float(x.std(ddof=1) / np.sqrt(len(x))), "relative": float(rel)},
           "mean_grey": grey, "args": vars(args), **run_metadata()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print("→", args.out)


if __name__ == "__main__":
    main()
