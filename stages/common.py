"""What every DVC stage entry point shares: the resolved config, one MLflow run per execution, clean errors.

A stage module is ten lines:

    from stages.common import stage_main

    def run(cfg: dict, tracker) -> None:
        ...  # call the library, write outputs atomically, tracker.log_metrics(...)

    if __name__ == "__main__":
        stage_main("features", run)

`stage_main` loads `configs/resolved.yaml`, opens an MLflow run tagged with the stage name, git commit and a hash of
the stage's own config keys (STAGE_KEYS, which dvc.yaml declares as the stage's `params`), calls `run`, and turns an
`expoctl.errors.InputError` into a one-line message and exit code 2 — no traceback, and since every writer is
atomic, no partial output.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

import yaml

from expoctl.errors import InputError

PROJECT_ROOT = Path(__file__).resolve().parents[1]
RESOLVED_CONFIG = PROJECT_ROOT / "configs" / "resolved.yaml"
EXPERIMENT_NAME = "expoctl"

#: The keys of configs/resolved.yaml each stage reads. dvc.yaml declares exactly these as the stage's params
#: (tests/pipeline/test_dvc_yaml.py checks that they agree), so `dvc repro` re-runs a stage only when they change.
STAGE_KEYS: dict[str, list[str]] = {
    "collect": ["seed", "sensor", "world", "rig", "collect", "controllers.agae", "paths.raw_dir"],
    "ingest": ["ingest", "paths.raw_dir", "paths.frames", "paths.images_dir"],
    "features": ["features", "paths.frames", "paths.features", "paths.matches"],
    "labels": ["labels", "paths.frames", "paths.features", "paths.matches", "paths.labels", "paths.reports_dir"],
    "samples": ["samples", "paths.frames", "paths.labels", "paths.samples"],
    "train": ["seed", "model", "train", "paths.samples", "paths.frames", "paths.images_dir", "paths.model",
              "paths.reports_dir"],
    "evaluate": ["seed", "sensor", "world", "rig", "controllers", "features", "evaluate", "iteration2.paths.model",
                 "paths.frames", "paths.reports_dir"],
    "report": ["report", "paths.reports_dir"],
}


#: What an iteration-2 stage reads beyond its base stage's keys and `iteration2` (collect_iter2: the iteration-1 model).
ITERATION2_EXTRA_KEYS: dict[str, list[str]] = {"collect": ["iteration2.collect", "paths.model"]}


def stage_keys(stage: str) -> list[str]:
    """Config keys of a DVC stage; `<name>_iter2` reads its base stage's keys plus the `iteration2` block."""
    if stage.endswith("_iter2"):
        base = stage.removesuffix("_iter2")
        return STAGE_KEYS[base] + ["iteration2.enabled", "iteration2.paths"] + ITERATION2_EXTRA_KEYS.get(base, [])
    return STAGE_KEYS.get(stage, [])


def for_iteration(cfg: dict[str, Any], iteration: int) -> dict[str, Any]:
    """The config a stage sees in the paper's data-collection iteration `iteration` (1 or 2).

    Iteration 2 (the trained network becomes camera 1's reference, more data is collected, and the model is retrained
    on both sets) runs the same stage code on its own paths: `paths` becomes `iteration2.paths`, while the
    iteration-1 paths stay readable as `paths_iter1` (ingest reads both raw directories, features reuses the
    iteration-1 counts, collect takes the iteration-1 model as reference).
    """
    if iteration == 1:
        return cfg
    if iteration != 2:
        raise InputError(f"--iteration must be 1 or 2, got {iteration}")
    it2 = cfg.get("iteration2")
    if not isinstance(it2, dict) or not isinstance(it2.get("paths"), dict):
        raise InputError(f"{RESOLVED_CONFIG}: config key 'iteration2.paths' is missing")
    out = dict(cfg)
    out["paths_iter1"] = dict(cfg["paths"])
    out["paths"] = {**cfg["paths"], **it2["paths"]}
    out["iteration"] = 2
    return out


def main_project_root(start: Path = PROJECT_ROOT) -> Path:
    """The user's project root, also from inside a `dvc exp run --queue` workspace copy.

    DVC runs queued experiments in copies under `<root>/.dvc/tmp/exps/...`; a store path computed there would be lost
    with the copy, so cut the path at `.dvc`.
    """
    parts = start.parts
    if ".dvc" in parts:
        return Path(*parts[: parts.index(".dvc")])
    return start


def tracking_uri() -> str:
    """MLFLOW_TRACKING_URI if set, else the embedded SQLite store at an absolute path in the project root."""
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{main_project_root() / 'mlflow.db'}"


def init_tracking(experiment: str = EXPERIMENT_NAME) -> str:
    """Create the store and the experiment (artifacts beside the store) if missing; return the experiment id.

    Run this once before any parallel fan-out: two processes migrating a fresh SQLite store at once race.
    """
    import mlflow

    mlflow.set_tracking_uri(tracking_uri())
    exp = mlflow.get_experiment_by_name(experiment)
    if exp is not None:
        return exp.experiment_id
    artifacts = None
    if tracking_uri().startswith("sqlite:"):
        artifacts = (main_project_root() / "mlartifacts").as_uri()
    return mlflow.create_experiment(experiment, artifact_location=artifacts)


def load_resolved(path: Path = RESOLVED_CONFIG) -> dict[str, Any]:
    if not path.exists():
        raise InputError(f"{path}: missing; run the compose stage first (dvc repro compose)")
    cfg = yaml.safe_load(path.read_text())
    if not isinstance(cfg, dict):
        raise InputError(f"{path}: not a YAML mapping")
    return cfg


def select_keys(cfg: dict[str, Any], keys: list[str]) -> dict[str, Any]:
    """The sub-config named by dotted keys, e.g. ["features", "paths.frames"] → {"features": …, "paths.frames": …}."""
    out = {}
    for key in keys:
        node: Any = cfg
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                raise InputError(f"{RESOLVED_CONFIG}: config key '{key}' is missing")
            node = node[part]
        out[key] = node
    return out


def config_hash(sub: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(sub, sort_keys=True, default=str).encode()).hexdigest()[:16]


def flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict → {"a.b.c": value}; lists become their JSON text."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, key + "."))
        elif isinstance(v, (list, tuple)):
            out[key] = json.dumps(v, default=str)
        else:
            out[key] = v
    return out


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=PROJECT_ROOT, capture_output=True, text=True,
                              timeout=10).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


class Tracker:
    """The MLflow calls a stage makes, on the active run (kept small so stages stay testable with a fake)."""

    def __init__(self, mlflow_module):
        self._mlflow = mlflow_module

    def log_params(self, params: dict[str, Any]) -> None:
        flat = {k: (str(v)[:6000] if v is not None else "null") for k, v in flatten(params).items()}
        items = list(flat.items())
        for i in range(0, len(items), 100):  # MLflow caps a batch at 100 params
            self._mlflow.log_params(dict(items[i : i + 100]))

    def log_metrics(self, metrics: dict[str, float], step: int | None = None) -> None:
        clean = {k: float(v) for k, v in flatten(metrics).items() if isinstance(v, (int, float)) and not isinstance(v, bool)}
        if clean:
            self._mlflow.log_metrics(clean, step=step)

    def log_artifact(self, path: str | os.PathLike, artifact_path: str | None = None) -> None:
        p = Path(path)
        if p.is_dir():
            self._mlflow.log_artifacts(str(p), artifact_path=artifact_path or p.name)
        elif p.exists():
            self._mlflow.log_artifact(str(p), artifact_path=artifact_path)

    def set_tags(self, tags: dict[str, Any]) -> None:
        self._mlflow.set_tags({k: str(v) for k, v in tags.items()})

    @property
    def run_id(self) -> str:
        return self._mlflow.active_run().info.run_id


@contextmanager
def tracked_run(stage: str, cfg: dict[str, Any]) -> Iterator[Tracker]:
    """One MLflow run for one stage execution, with params = the stage's config keys."""
    import mlflow

    experiment_id = init_tracking()
    sub = select_keys(cfg, stage_keys(stage))
    with mlflow.start_run(experiment_id=experiment_id, run_name=stage):
        tracker = Tracker(mlflow)
        tracker.set_tags({"stage": stage, "git_commit": git_commit(), "config_hash": config_hash(sub),
                          "scale": cfg.get("scale_name", "unknown")})
        tracker.log_params(sub)
        t0 = time.perf_counter()
        yield tracker
        tracker.log_metrics({"stage_seconds": time.perf_counter() - t0})


def stage_main(stage: str, run: Callable[[dict[str, Any], Tracker], None]) -> None:
    """Entry point of a DVC stage: run it tracked; user-caused errors print one line and exit 2.

    `python -m stages.<name> --iteration 2` runs the stage for the paper's second data-collection iteration
    (see `for_iteration`); its MLflow run and DVC stage are called `<name>_iter2`.
    """
    import argparse

    parser = argparse.ArgumentParser(prog=f"python -m stages.{stage}")
    parser.add_argument("--iteration", type=int, default=1, choices=(1, 2))
    args = parser.parse_args()
    name = stage if args.iteration == 1 else f"{stage}_iter2"
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
