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
from expoctl.host import host_cpu

PROJECT_ROOT = Path(__file__).resolve().parents[1]
RESOLVED_CONFIG = PROJECT_ROOT / "configs" / "resolved.yaml"
EXPERIMENT_NAME = "expoctl"

#: Data-collection iterations run as stages `<name>_iter<N>`, N = 2 … LAST_ITERATION (conf/config.yaml `iteration<N>`
#: blocks). The final model, which evaluate drives, is the one select_model chooses among them (paths.final_model).
LAST_ITERATION = 3

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
    # select_model reads every iteration's enabled flag and model path: the candidates
    "select_model": ["seed", "sensor", "world", "rig", "controllers", "features", "evaluate", "select_model",
                     "paths.model", "paths.final_model", "paths.frames", "paths.reports_dir"]
                    + [f"iteration{n}.{k}" for n in range(2, LAST_ITERATION + 1) for k in ("enabled", "paths.model")],
    "evaluate": ["seed", "sensor", "world", "rig", "controllers", "features", "evaluate", "paths.final_model",
                 "paths.frames", "paths.reports_dir"],
    "report": ["report", "paths.reports_dir"],
}


def split_stage_name(stage: str) -> tuple[str, int]:
    """'features_iter3' → ('features', 3); 'features' → ('features', 1)."""
    base, sep, n = stage.rpartition("_iter")
    if sep and n.isdigit() and int(n) >= 2:
        return base, int(n)
    return stage, 1


def stage_keys(stage: str) -> list[str]:
    """Config keys of a DVC stage. `<name>_iter<N>` reads its base stage's keys, its own `iteration<N>` block's
    `enabled` and `paths`, and every earlier iteration's paths (its raw directories are ingested again, the previous
    model is collect's reference, the previous tables are reused); collect also reads `iteration<N>.collect`."""
    base, n = split_stage_name(stage)
    if n == 1:
        return STAGE_KEYS.get(stage, [])
    keys = STAGE_KEYS[base] + [f"iteration{n}.enabled", f"iteration{n}.paths"]
    keys += [f"iteration{k}.paths" for k in range(2, n)]
    if base == "collect":  # iterations ≥ 2 drive camera 1 with the learned network (its latency_frames)
        keys += ["controllers.learned", f"iteration{n}.collect"] + (["paths.model"] if n == 2 else [])
    return keys


def for_iteration(cfg: dict[str, Any], iteration: int) -> dict[str, Any]:
    """The config a stage sees in the paper's data-collection iteration `iteration` (1 … LAST_ITERATION).

    Iteration N ≥ 2 (the previous iteration's network becomes camera 1's reference, more data is collected, and the
    model is retrained on all data so far) runs the same stage code on its own paths: `paths` becomes
    `iteration<N>.paths` over the base paths, `paths_prev` holds the previous iteration's paths (collect's reference
    model, the tables features reuses, the model train keeps when the iteration is disabled), `raw_dirs_prev` every
    earlier iteration's raw directory (ingest reads them all, oldest first) and `iteration_block` the `iteration<N>`
    block itself.
    """
    if iteration == 1:
        return cfg
    if not 2 <= iteration <= LAST_ITERATION:
        raise InputError(f"--iteration must be 1 … {LAST_ITERATION}, got {iteration}")
    paths = [cfg.get("paths") or {}]
    for k in range(2, iteration + 1):
        block = cfg.get(f"iteration{k}")
        if not isinstance(block, dict) or not isinstance(block.get("paths"), dict):
            raise InputError(f"{RESOLVED_CONFIG}: config key 'iteration{k}.paths' is missing")
        paths.append({**paths[0], **block["paths"]})
    out = dict(cfg)
    out["paths"] = paths[-1]
    out["paths_prev"] = paths[-2]
    out["raw_dirs_prev"] = [p["raw_dir"] for p in paths[:-1]]
    out["iteration_block"] = cfg[f"iteration{iteration}"]
    out["iteration"] = iteration
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
                          "scale": cfg.get("scale_name", "unknown"), "host_cpu": host_cpu()})
        tracker.log_params(sub)
        t0 = time.perf_counter()
        yield tracker
        tracker.log_metrics({"stage_seconds": time.perf_counter() - t0})


def stage_main(stage: str, run: Callable[[dict[str, Any], Tracker], None]) -> None:
    """Entry point of a DVC stage: run it tracked; user-caused errors print one line and exit 2.

    `python -m stages.<name> --iteration N` runs the stage for the N-th data-collection iteration (see
    `for_iteration`); its MLflow run and DVC stage are called `<name>_iter<N>`.
    """
    import argparse

    parser = argparse.ArgumentParser(prog=f"python -m stages.{stage}")
    parser.add_argument("--iteration", type=int, default=1, choices=range(1, LAST_ITERATION + 1))
    args = parser.parse_args()
    name = stage if args.iteration == 1 else f"{stage}_iter{args.iteration}"
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
