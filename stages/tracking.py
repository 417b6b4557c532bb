"""MLflow tracking for the stages: one run per stage execution, with the stage's config keys as params.

The store is MLFLOW_TRACKING_URI if set, else an SQLite file in the project root (MLflow 3.13+ refuses a plain
./mlruns file store). `init_tracking` creates it; call it once before any parallel fan-out.
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

from expoctl.host import host_cpu
from stages.keys import config_hash, runtime_keys, select_keys, stage_keys
from stages.project import PROJECT_ROOT, main_project_root

EXPERIMENT_NAME = "expoctl"
# the per-(controller, city) metrics the MLflow UI's saved view shows as columns (docs/pipeline.md#the-mlflow-ui),
# sorted by the first: the paper's headline, the worst dynamic-window NFM
LEADERBOARD_METRICS = ("dynamic.orb.min_nfm", "dynamic.orb.median_nfm", "dynamic.viso.min_nfm",
                       "static.orb.median_nfm", "tracking_success_rate", "controller_ms_median_mean")


def tracking_uri() -> str:
    """MLFLOW_TRACKING_URI if set, else the embedded SQLite store at an absolute path in the project root."""
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{main_project_root() / 'mlflow.db'}"


def init_tracking(experiment: str = EXPERIMENT_NAME) -> str:
    """Create the store and the experiment (artifacts beside the store) if missing; return the experiment id.

    The pipeline's experiment (also one made before this existed) is set up to open in the MLflow UI on its runs
    table with the leaderboard columns (`set_compare_view`). Run this once before any parallel fan-out: two
    processes migrating a fresh SQLite store at once race.
    """
    import mlflow

    mlflow.set_tracking_uri(tracking_uri())
    exp = mlflow.get_experiment_by_name(experiment)
    if exp is not None:
        experiment_id = exp.experiment_id
    else:
        artifacts = None
        if tracking_uri().startswith("sqlite:"):
            artifacts = (main_project_root() / "mlartifacts").as_uri()
        experiment_id = mlflow.create_experiment(experiment, artifact_location=artifacts)
    if experiment == EXPERIMENT_NAME:
        set_compare_view(experiment_id)
    return experiment_id


def set_compare_view(experiment_id: str, evaluate_run: str | None = None) -> str:
    """Make the MLflow UI open the experiment on the runs table, the per-controller runs flat with the leaderboard
    metrics as columns; `evaluate_run`: show that evaluate run's controllers (None: keep the view's filter). Writes
    only what changed (one read per stage run otherwise). Returns the view's address below the server root."""
    from expoctl.tracking_ui import set_runs_view

    search = None if evaluate_run is None else f"tags.parent_stage_run = '{evaluate_run}'"
    return set_runs_view(experiment_id, metrics=LEADERBOARD_METRICS, order_by=LEADERBOARD_METRICS[0],
                         search_filter=search)


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
def tracked_run(stage: str, cfg: dict[str, Any], numerics: dict[str, Any] | None = None) -> Iterator[Tracker]:
    """One MLflow run for one stage execution, with params = the stage's config keys (and its runtime keys, which
    `config_hash` leaves out: they never change a result) and, given `numerics` (expoctl.numerics.record), tags
    saying which numeric mode, libraries and CPU flags it ran with."""
    import mlflow

    experiment_id = init_tracking()
    sub = select_keys(cfg, stage_keys(stage))
    runtime = {k: v for k, v in select_keys(cfg, [k for k in runtime_keys(stage) if k in cfg]).items()}
    with mlflow.start_run(experiment_id=experiment_id, run_name=stage):
        tracker = Tracker(mlflow)
        tracker.set_tags({"stage": stage, "git_commit": git_commit(), "config_hash": config_hash(sub),
                          "scale": cfg.get("scale_name", "unknown"), "host_cpu": host_cpu()})
        if numerics is not None:
            from expoctl.numerics import tags as numerics_tags

            tracker.set_tags(numerics_tags(numerics))
        tracker.log_params({**sub, **runtime})
        t0 = time.perf_counter()
        yield tracker
        tracker.log_metrics({"stage_seconds": time.perf_counter() - t0})
