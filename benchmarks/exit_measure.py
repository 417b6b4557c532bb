"""Tunnel exits under the causal baselines: how deep the dynamic dip is, how long the image stays white, and VO.

For every (route split, controller) of an evaluation it prints:
- `dyn/stat`: the dynamic-section minimum over the static-section median of ORB inlier matches (NFM); the paper's
  AG+AE on its real rig: 0.09;
- the frames more than 50 % saturated (grey ≥ 250) in each exit window (frames from 2.5 s before to 4 s after an exit
  portal: the most saturated frames come just before it, when the opening fills the view), per run, and the longest
  such run of consecutive frames;
- VO successes, frame to frame and against the local map (`expoctl.vo.frame_to_frame`, `expoctl.vo.local_map`).

Two modes:
    .venv/bin/python benchmarks/exit_measure.py summarise REPORTS_EVAL_DIR [...]
        summarise evaluate outputs already written (reports/eval/ of a `dvc repro`);
    .venv/bin/python benchmarks/exit_measure.py run --case NAME OVERRIDE [OVERRIDE ...] [--case NAME ...]
        run the evaluation (expoctl.evaluation.runner) for each case, with evaluate.controllers=[agae,fixed,mean_intensity]
        unless an override says otherwise (--keep DIR also writes each case's outputs to DIR/NAME), in this project (its train split must have been collected: evaluate tunes
        SumLog on it), and summarise. Example: --case underpass world.cities.test=underpass ~evaluate.splits.validation

Writes benchmarks/results/exit_measure.json (or --out).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "src"), str(ROOT)]

from bench_meta import run_metadata  # noqa: E402

from expoctl.errors import ConfigError, InputError  # noqa: E402
from expoctl.io import write_json  # noqa: E402

PAPER_AGAE_DYN_OVER_STATIC = 0.09
EXIT_WINDOW_S = (-2.5, 4.0)  # around an exit portal: its dynamic span before it (the portal fills the view) and 4 s after
HALF_SATURATED = 0.5


def _longest_run(mask: np.ndarray) -> int:
    best = cur = 0
    for m in mask:
        cur = cur + 1 if m else 0
        best = max(best, cur)
    return best


def summarise(frames: pd.DataFrame, runs: pd.DataFrame, metrics: dict) -> dict:
    out: dict = {}
    for (split, ctrl), r in runs.groupby(["route_split", "controller"], sort=True):
        m = metrics.get(split, {}).get(ctrl, {})
        stat = m.get("static", {}).get("orb", {}).get("median_nfm", float("nan"))
        dyn = m.get("dynamic", {}).get("orb", {}).get("min_nfm", float("nan"))
        exits, losses = [], []  # losses: where VO lost track (frame of the window, nearest portal, exposure state)
        for _, run in r.sort_values("run_id").iterrows():
            f = frames[frames.run_id == run.run_id].sort_values("frame").reset_index(drop=True)
            for col in ("vo_failed_at", "vo_map_failed_at"):
                k = int(run[col]) if col in run and run[col] is not None and run[col] >= 0 else -1
                hit = np.flatnonzero(f["frame"].to_numpy() == k)
                if k >= 0 and hit.size:
                    k = int(hit[0])
                    losses.append({"run_id": str(run.run_id), "test": "map" if "map" in col else "frame_to_frame",
                                   "frame": k, "portal": str(f.portal_kind[k]),
                                   "portal_dt_s": round(float(f.portal_dt_s[k]), 2),
                                   "saturated_frac": round(float(f.saturated_frac[k]), 3),
                                   "mean_grey": round(float(f.mean_grey[k]), 1)})
        for _, run in r.sort_values("run_id").iterrows():
            f = frames[frames.run_id == run.run_id].sort_values("frame")
            at_exit = (f.portal_kind == "exit") & f.portal_dt_s.between(*EXIT_WINDOW_S)
            if not at_exit.any():
                continue
            sat = f.loc[at_exit, "saturated_frac"].to_numpy(float) > HALF_SATURATED
            exits.append({"run_id": str(run.run_id), "frames_over_half_saturated": int(sat.sum()),
                          "longest_run": _longest_run(sat),
                          "max_saturated_frac": float(f.loc[at_exit, "saturated_frac"].max())})
        out.setdefault(split, {})[ctrl] = {
            "static_median_orb": stat, "dynamic_min_orb": dyn,
            "dyn_over_static": dyn / stat if stat and math.isfinite(stat) and stat > 0 else float("nan"),
            "exits": exits, "vo_losses": losses,
            "vo_success": [int(r.vo_success.sum()), int(len(r))],
            "vo_map_success": [int(r.vo_map_success.sum()), int(len(r))] if "vo_map_success" in r else None,
            "vo_min_inliers": int(r.vo_min_inliers.min()),
            "vo_map_min_inliers": int(r.vo_map_min_inliers.min()) if "vo_map_min_inliers" in r else None,
        }
    return out


def print_summary(case: str, s: dict) -> None:
    print(f"\n[{case}] (paper's AG+AE dyn/stat: {PAPER_AGAE_DYN_OVER_STATIC})")
    print(f"  {'split':10s} {'controller':15s} {'stat med':>8s} {'dyn min':>7s} {'dyn/stat':>8s} | "
          f"{'exit frames >50% sat (longest run)':36s} | {'VO f2f':>6s} {'VO map':>6s} {'min f2f/map':>11s}")
    for split, ctrls in s.items():
        for ctrl, v in ctrls.items():
            ex = ", ".join(f"{e['frames_over_half_saturated']}({e['longest_run']})" for e in v["exits"]) or "—"
            vm = v["vo_map_success"] or ["—", "—"]
            print(f"  {split:10s} {ctrl:15s} {v['static_median_orb']:8.0f} {v['dynamic_min_orb']:7.0f} "
                  f"{v['dyn_over_static']:8.2f} | {ex:36s} | {v['vo_success'][0]:>2}/{v['vo_success'][1]:<3} "
                  f"{vm[0]:>2}/{vm[1]:<3} {v['vo_min_inliers']:>5}/{v['vo_map_min_inliers']}")
            for lo in v.get("vo_losses", []):
                print(f"  {'':26s}   lost ({lo['test']}) at frame {lo['frame']}: {lo['portal']} {lo['portal_dt_s']:+.2f} s, "
                      f"{100 * lo['saturated_frac']:.0f} % saturated, mean grey {lo['mean_grey']:.0f}")


def load_eval_dir(d: Path) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    import json

    missing = [p for p in ("frames.parquet", "runs.parquet") if not (d / p).is_file()]
    metrics_path = d.parent / "metrics.json"
    if not metrics_path.is_file():
        missing.append(str(metrics_path))
    if missing:
        raise InputError(f"{d}: not an evaluate output directory (missing {', '.join(missing)})")
    return pd.read_parquet(d / "frames.parquet"), pd.read_parquet(d / "runs.parquet"), json.loads(metrics_path.read_text())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    s1 = sub.add_parser("summarise")
    s1.add_argument("eval_dirs", nargs="+", type=Path)
    s2 = sub.add_parser("run")
    s2.add_argument("--case", nargs="+", action="append", required=True, metavar=("NAME", "OVERRIDE"))
    s2.add_argument("--keep", type=Path, metavar="DIR",
                    help="also write each case's evaluate outputs to DIR/NAME (eval/ and metrics.json, as the stage "
                         "writes them), e.g. for benchmarks/paper_tables.py")
    for p in (s1, s2):
        p.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "exit_measure.json")
    args = ap.parse_args()
    t0 = time.time()
    results = {}
    try:
        if args.mode == "summarise":
            for d in args.eval_dirs:
                results[str(d)] = summarise(*load_eval_dir(d))
        else:
            from expoctl.evaluation.inputs import EvaluationInputs
            from expoctl.evaluation.runner import evaluate, write_outputs
            from expoctl.parallel import ParallelConfig
            from stages.compose import compose_config

            for name, *overrides in args.case:
                if not any(o.startswith("evaluate.controllers=") for o in overrides):
                    overrides = ["evaluate.controllers=[agae,fixed,mean_intensity]", *overrides]
                t1 = time.time()
                cfg = compose_config(list(overrides))  # parallel.n_jobs=2 in a case: two worker processes
                res = evaluate(EvaluationInputs.from_resolved(cfg), ROOT, parallel=ParallelConfig.from_resolved(cfg))
                if args.keep:
                    write_outputs(res, args.keep / name)
                results[name] = summarise(res.frames, res.runs, res.metrics)
                results[name]["_overrides"] = list(overrides)
                results[name]["_seconds"] = round(time.time() - t1, 1)
                print(f"[exit_measure] {name}: {time.time() - t1:.0f} s", file=sys.stderr, flush=True)
    except (ConfigError, InputError) as exc:
        print(f"exit_measure: {exc}", file=sys.stderr)
        return 2
    for case, s in results.items():
        print_summary(case, {k: v for k, v in s.items() if not k.startswith("_")})
    write_json({"cases": results, "seconds": round(time.time() - t0, 1), **run_metadata()}, args.out)
    print(f"\nwrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
