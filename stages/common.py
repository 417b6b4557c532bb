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
import time
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
    started = time.time()  # an output modified after this was replaced by this run
    logging.basicConfig(level=logging.INFO, format=f"[{name}] %(message)s")
    logging.getLogger("alembic").setLevel(logging.WARNING)
    try:
        cfg = for_iteration(load_resolved(), args.iteration)
        with tracked_run(name, cfg) as tracker:
            run(cfg, tracker)
    except InputError as exc:
        print(f"expoctl {stage}: error: {exc}\n{outputs_left(name, started)}", file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print(f"expoctl {stage}: interrupted.\n{outputs_left(name, started)}", file=sys.stderr)
        sys.exit(130)
    except Exception:
        print(f"expoctl {stage}: failed (a bug: please report the traceback below).\n{outputs_left(name, started)}",
              file=sys.stderr)
        raise


def outputs_left(dvc_stage: str, started: float) -> str:
    """What a stage that stopped early leaves. dvc.yaml declares every output `persist: true`, so DVC did not delete
    them, and every writer is atomic, so none is half-written: each is either as the last run left it or, if this run
    got as far as writing it (modified after `started`), already replaced."""
    import datetime

    from stages.dvcfile import declared_outputs

    try:
        outs = [o.path for o in declared_outputs(PROJECT_ROOT) if o.stage == dvc_stage]
    except Exception:  # noqa: BLE001 — the message must not hide the original error
        return "(dvc.yaml could not be read to list its outputs; each is written atomically, so none is half-written.)"
    if not outs:
        return "It has no declared outputs."
    kept, replaced, missing = [], [], []
    for rel in outs:
        p = PROJECT_ROOT / rel
        if not p.exists():
            missing.append(rel)
        elif p.stat().st_mtime >= started:
            replaced.append(rel)
        else:
            when = datetime.datetime.fromtimestamp(p.stat().st_mtime).strftime("%Y-%m-%d %H:%M")
            kept.append(f"{rel} ({when})")
    lines = []
    if kept:
        lines.append("Left as before, not replaced: " + ", ".join(kept) + ".")
    if replaced:
        lines.append("Already replaced by this run before it stopped: " + ", ".join(replaced) + ".")
    if missing:
        lines.append("Not produced yet: " + ", ".join(missing) + ".")
    lines.append(f"`dvc status` lists '{dvc_stage}' as changed; the next `dvc repro` runs it again.")
    return "\n".join(lines)
