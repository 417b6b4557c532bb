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
from stages.numerics import numerics_for
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
        numerics = numerics_for(cfg)  # the mode stages/__init__.py applied at start; its record goes to MLflow
        if copied_when_disabled(stage, cfg):
            return
        with tracked_run(name, cfg, numerics) as tracker:
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


#: What a stage of a disabled later iteration would recompute unchanged (its collect records no sequences, so its data
#: is the previous iteration's): `paths` keys of files and directories, and file names under `paths.reports_dir`.
#: They are copied instead, with no MLflow run. collect (an empty raw directory) and train (its own copy, logged) run.
COPIED_WHEN_DISABLED: dict[str, tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]]] = {
    "ingest": (("frames",), ("images_dir",), ()),
    "features": (("features", "matches"), (), ()),
    "labels": (("labels",), (), ("labels.md", "labels.json")),
    "samples": (("samples",), (), ()),
}


def copied_when_disabled(stage: str, cfg: dict[str, Any]) -> bool:
    """For a stage of a disabled iteration N >= 2 in COPIED_WHEN_DISABLED: copy iteration N-1's outputs atomically
    and say so in one line; True if it did (nothing else to do)."""
    import shutil

    from expoctl.io import atomic_dir, atomic_path

    if cfg.get("iteration", 1) == 1 or stage not in COPIED_WHEN_DISABLED or cfg["iteration_block"].get("enabled", True):
        return False
    n, prev, paths = cfg["iteration"], cfg["paths_prev"], cfg["paths"]
    files, dirs, reports = COPIED_WHEN_DISABLED[stage]
    pairs = [(prev[k], paths[k]) for k in files + dirs]
    pairs += [(f"{prev['reports_dir']}/{r}", f"{paths['reports_dir']}/{r}") for r in reports]
    missing = [src for src, _ in pairs if not (PROJECT_ROOT / src).exists()]
    if missing:
        raise InputError(f"iteration {n} is disabled, so {stage} copies iteration {n - 1}'s outputs, but "
                         f"{', '.join(missing)} {'is' if len(missing) == 1 else 'are'} missing (run its stages first)")
    for src, dst in pairs:
        if (PROJECT_ROOT / src).is_dir():
            with atomic_dir(PROJECT_ROOT / dst) as tmp:
                shutil.copytree(PROJECT_ROOT / src, tmp, dirs_exist_ok=True)
        else:
            with atomic_path(PROJECT_ROOT / dst) as tmp:
                shutil.copyfile(PROJECT_ROOT / src, tmp)
    logging.getLogger(__name__).info("iteration %d is disabled (iteration%d.enabled: false): copied iteration %d's %s",
                                     n, n, n - 1, ", ".join(dst for _, dst in pairs))
    return True


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
