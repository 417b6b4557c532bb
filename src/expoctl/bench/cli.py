"""expoctl bench: score a gain/exposure controller on the benchmark routes against every baseline and the oracle.

    expoctl bench --controller my_pkg.ctl:HoldController      # an import path (the current directory is importable)
    expoctl bench --controller halfway                        # a registered or installed plugin's name
    expoctl bench --scale fixture --no-mlflow                 # the small packaged benchmark (seconds, not minutes)

Prints the leaderboard (docs/benchmark.md, Reading the leaderboard), writes leaderboard.json and leaderboard.txt to
--out (swapped in whole), and logs one MLflow run per controller to the experiment `expoctl-bench`. Nothing is
written when a controller, the config or the model is wrong: every problem is named first.

Config: --config a resolved config (a project's configs/resolved.yaml); else, in a project (configs/resolved.yaml
in --project), that one, so the numbers are the evaluate stage's; else the benchmark config packaged with expoctl
(--scale default | fixture).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from expoctl.errors import ConfigError, InputError

EXPERIMENT = "expoctl-bench"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--controller", action="append", default=[], metavar="NAME|module:Class",
                   help="a controller to score beside the baselines (repeatable): a registered name or an import path")
    p.add_argument("--baselines", metavar="NAME,...",
                   help="score only these registered controllers beside --controller (default: every one, the "
                        "learned network when a trained model exists, and the oracle)")
    p.add_argument("--config", type=Path, help="a resolved config (default: the project's, else the packaged one)")
    p.add_argument("--scale", choices=("default", "fixture"), default="default",
                   help="the packaged benchmark config, when no project config is used (default: default)")
    p.add_argument("--project", type=Path, default=Path("."),
                   help="project root: training frames for SumLog, the trained model (default: .)")
    p.add_argument("--traversals", type=int, help="traversals per split (default: the config's, 1)")
    p.add_argument("--model", type=Path, help="the learned network to score (default: the project's final model)")
    p.add_argument("--n-jobs", type=int, help="worker processes (default: the config's parallel.n_jobs)")
    p.add_argument("--out", type=Path, default=Path("bench"), help="output folder (default: ./bench)")
    p.add_argument("--mlflow-uri", help="MLflow tracking URI (default: $MLFLOW_TRACKING_URI, else sqlite:///mlflow.db)")
    p.add_argument("--experiment", default=EXPERIMENT, help=f"MLflow experiment (default: {EXPERIMENT})")
    p.add_argument("--no-mlflow", action="store_true", help="do not log to MLflow")
    p.add_argument("--bound", action="store_true",
                   help="also the offline optimum over the oracle's candidate grid (K² matches per frame: slow)")
    p.add_argument("--width", type=int, default=120, help="leaderboard width in columns (default: 120)")


def run(args: argparse.Namespace) -> int:
    from expoctl.bench.config import load_benchmark_config
    from expoctl.bench.report import benchmark_json, write_outputs
    from expoctl.bench.score import plan_benchmark, run_benchmark

    # an import path names a module of the current directory, as `python -m` would find it
    if "" not in sys.path and str(Path.cwd()) not in sys.path:
        sys.path.insert(0, str(Path.cwd()))
    if args.n_jobs is not None and args.n_jobs < 1:
        raise ConfigError("--n-jobs", f"must be >= 1, got {args.n_jobs}")
    if args.width < 80:
        raise ConfigError("--width", f"must be >= 80 columns, got {args.width}")
    check_out_dir(args.out)
    cfg, source = load_benchmark_config(args.config, args.project, args.scale)
    baselines = None if args.baselines is None else [b.strip() for b in args.baselines.split(",") if b.strip()]
    plan = plan_benchmark(cfg, args.project, args.controller, args.traversals, args.model, args.n_jobs, baselines)
    tracking = None
    if not args.no_mlflow:
        from expoctl.bench.tracking import open_experiment

        tracking = open_experiment(args.mlflow_uri, args.experiment, args.project)  # fails before any work
    for name, why in plan.skipped.items():
        print(f"expoctl bench: not scoring {name!r}: {why}", file=sys.stderr)
    print(f"expoctl bench: {len(plan.controllers)} controllers × {len(plan.windows)} windows ({source})",
          file=sys.stderr)
    outcome = run_benchmark(plan, args.project, progress=sys.stderr.isatty(), bound=args.bound)
    doc = benchmark_json(outcome, source)
    text = write_outputs(doc, args.out, args.width)
    print(text)
    if tracking is not None:
        from expoctl.bench.tracking import log_benchmark

        configs = {name: plan.inputs.controller_config(name) for name in plan.controllers}
        ids = log_benchmark(tracking, doc, args.out, configs)
        from expoctl.tracking_ui import runs_view_path

        print(f"expoctl bench: {len(ids)} MLflow runs in experiment {args.experiment!r} ({tracking.uri}); "
              f"`mlflow ui --backend-store-uri {tracking.uri}`, then open "
              f"{runs_view_path(tracking.experiment_id, 'expoctl-bench-leaderboard')}", file=sys.stderr)
    print(f"expoctl bench: wrote {args.out / 'leaderboard.json'}", file=sys.stderr)
    return 0


def check_out_dir(out: Path) -> None:
    """--out is swapped in whole: refuse a folder that holds anything but an earlier benchmark's outputs."""
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: --out must be a folder, and this is a file")
    if out.is_dir():
        foreign = sorted(p.name for p in out.iterdir() if p.name not in ("leaderboard.json", "leaderboard.txt"))
        if foreign:
            raise InputError(f"{out}: --out holds other files ({', '.join(foreign[:5])}), which the benchmark "
                             "would replace; give an empty or new folder")


def main(argv: list[str] | None = None) -> int:  # `python -m expoctl.bench.cli`
    p = argparse.ArgumentParser(prog="expoctl bench", description=__doc__.splitlines()[0])
    add_arguments(p)
    args = p.parse_args(argv)
    try:
        return run(args)
    except InputError as exc:
        print(f"expoctl bench: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
