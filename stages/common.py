"""The entry point every DVC stage shares: the resolved config, one MLflow run per execution, clean errors.

A stage module is ten lines:

    from stages.common import PROJECT_ROOT, stage_main

    def run(cfg: dict, tracker) -> None:
        ...  # call the library, write outputs atomically, tracker.log_metrics(...)

    if __name__ == "__main__":
        stage_main("features", run)

`stage_main` loads `configs/resolved.yaml` (stages/project.py), derives the iteration's config (stages/iterations.py),
opens an MLflow run tagged with the stage name, git commit and a hash of the stage's own config keys (stages/keys.py,
which dvc.yaml declares as the stage's `params`; stages/tracking.py), calls `run`, and turns an
`expoctl.errors.InputError` into a one-line message and exit code 2 — no traceback, and since every writer is
atomic, no partial output.
"""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any, Callable

from expoctl.errors import InputError
from stages.iterations import for_iteration
from stages.keys import LAST_ITERATION, stage_name
from stages.project import PROJECT_ROOT, load_resolved
from stages.tracking import Tracker, tracked_run

__all__ = ["PROJECT_ROOT", "stage_main"]


def stage_main(stage: str, run: Callable[[dict[str, Any], Tracker], None]) -> None:
    """Entry point of a DVC stage: run it tracked; user-caused errors print one line and exit 2.

    `python -m stages.<name> --iteration N` runs the stage for the N-th data-collection iteration (see
    `for_iteration`); its MLflow run and DVC stage are called `<name>_iter@<N>`.
    """
    parser = argparse.ArgumentParser(prog=f"python -m stages.{stage}")
    parser.add_argument("--iteration", type=int, default=1, choices=range(1, LAST_ITERATION + 1))
    args = parser.parse_args()
    name = stage_name(stage, args.iteration)
    logging.basicConfig(level=logging.INFO, format=f"[{name}] %(message)s")
    logging.getLogger("alembic").setLevel(logging.WARNING)
    try:
        cfg = for_iteration(load_resolved(), args.iteration)
        with tracked_run(name, cfg) as tracker:
            run(cfg, tracker)
    except InputError as exc:
        print(f"expoctl {stage}: error: {exc}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print(f"expoctl {stage}: interrupted; no output was replaced", file=sys.stderr)
        sys.exit(130)
