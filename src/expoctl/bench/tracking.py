"""MLflow runs of a benchmark: one top-level run per controller in the experiment `expoctl-bench` (`expoctl bench`).

This module is the CLI's wiring to MLflow (as stages/tracking.py is the pipeline's); nothing else in the library
imports it, and it imports mlflow only when called.

Layout, chosen so the MLflow UI's runs table compares controllers as it opens: every run is top level (not a child
run the table collapses), named by the controller's label, tagged `controller`, `bench_id` (one per invocation:
filter `tags.bench_id = '…'` to see one leaderboard) and `reference` (true for the oracle); its metrics are the
leaderboard's cells: `<split>.<frontend>.static_median`, `.dynamic_median`, `.dynamic_min`,
`<split>.vo_tracked_rate`, `<split>.vo_map_tracked_rate` and `controller_ms`; its params the controller's typed config
and the benchmark's set-up. Each run also carries leaderboard.json as an artifact. The experiment's saved view
"Leaderboard (latest expoctl bench)" (`expoctl.tracking_ui`) shows the latest invocation's runs with those columns,
sorted by the last split's dynamic minimum; the experiment's description links to it.
"""

from __future__ import annotations

import json
import os
import time
import uuid
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any

from expoctl.errors import InputError
from expoctl.tracking_ui import set_runs_view


@dataclass(frozen=True)
class Tracking:
    uri: str
    experiment_id: str


def default_uri(project: str | os.PathLike) -> str:
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{(Path(project) / 'mlflow.db').resolve()}"


def open_experiment(uri: str | None, experiment: str, project: str | os.PathLike = ".") -> Tracking:
    """Connect to the store (created if missing) and the experiment (created if missing, artifacts beside an
    SQLite store), so that a bad URI stops the benchmark before any work."""
    try:
        import mlflow
    except ImportError:
        raise InputError("MLflow is not installed: pip install mlflow, or run with --no-mlflow") from None
    uri = uri or default_uri(project)
    try:
        mlflow.set_tracking_uri(uri)
        exp = mlflow.get_experiment_by_name(experiment)
        if exp is None:
            artifacts = None
            if uri.startswith("sqlite:///"):
                artifacts = (Path(uri[len("sqlite:///"):]).resolve().parent / "mlartifacts").as_uri()
            experiment_id = mlflow.create_experiment(experiment, artifact_location=artifacts)
        else:
            experiment_id = exp.experiment_id
    except Exception as exc:  # MLflow raises many types for a bad store
        raise InputError(f"MLflow store {uri!r}: cannot open experiment {experiment!r} ({type(exc).__name__}: "
                         f"{exc}); give --mlflow-uri or --no-mlflow") from None
    return Tracking(uri, experiment_id)


def run_metrics(row: dict[str, Any]) -> dict[str, float]:
    """The MLflow metrics of one leaderboard row (None cells left out)."""
    split, out = row["split"], {}
    for fe, cells in row["nfm"].items():
        for stat, v in cells.items():
            if v is not None:
                out[f"{split}.{fe}.{stat}"] = float(v)
    if row["vo_tracked"]:
        ok, n = row["vo_tracked"]
        out[f"{split}.vo_tracked_rate"] = ok / n if n else 0.0
    if row["vo_map_tracked"]:
        ok, n = row["vo_map_tracked"]
        out[f"{split}.vo_map_tracked_rate"] = ok / n if n else 0.0
    return out


def log_benchmark(tracking: Tracking, doc: dict[str, Any], out_dir: str | os.PathLike,
                  configs: dict[str, Any] | None = None) -> list[str]:
    """One run per controller of `doc` (benchmark_json's object); returns the run ids."""
    import mlflow

    mlflow.set_tracking_uri(tracking.uri)
    bench_id = time.strftime("%Y%m%dT%H%M%S") + "-" + uuid.uuid4().hex[:6]
    b = doc["benchmark"]
    common = {"bench.config": b["config"], "bench.seed": b["seed"], "bench.render_size": json.dumps(b["render_size"]),
              "bench.n_windows": len(b["windows"]), "bench.frontends": json.dumps(b["frontends"]),
              "bench.sumlog": b["sumlog"]}
    ids = []
    artifact = Path(out_dir) / "leaderboard.json"
    runs = dict(doc["controllers"])
    if doc.get("offline_bound"):
        from expoctl.bench.leaderboard import OFFLINE_OPTIMUM

        label = next(r["label"] for r in doc["leaderboard"] if r["controller"] == OFFLINE_OPTIMUM)
        runs[OFFLINE_OPTIMUM] = {"label": label, "reference": True, "package": "expoctl", "import_path": None}
    for name, c in runs.items():
        rows = [r for r in doc["leaderboard"] if r["controller"] == name]
        metrics: dict[str, float] = {}
        for r in rows:
            metrics.update(run_metrics(r))
        ms = [r["controller_ms"] for r in rows if r["controller_ms"] is not None]
        if ms:
            metrics["controller_ms"] = float(sorted(ms)[len(ms) // 2])
        tags = {"controller": name, "bench_id": bench_id, "reference": str(c["reference"]).lower(),
                "package": c["package"], "candidate": str(name in doc["candidates"]).lower()}
        with mlflow.start_run(experiment_id=tracking.experiment_id, run_name=c["label"], tags=tags) as run:
            params = {"controller": name, "import_path": c["import_path"] or "", **common}
            config = (configs or {}).get(name)
            if config is not None and is_dataclass(config):
                params.update({f"config.{f.name}": str(getattr(config, f.name))[:500] for f in fields(config)})
            mlflow.log_params(params)
            mlflow.log_metrics(metrics)
            if artifact.is_file():
                mlflow.log_artifact(str(artifact))
            ids.append(run.info.run_id)
    set_runs_view(tracking.experiment_id, metrics=view_metrics(doc), tags=["controller", "reference"],
                  order_by=view_metrics(doc)[0], search_filter=f"tags.bench_id = '{bench_id}'",
                  view_name="Leaderboard (latest expoctl bench)", view_id="expoctl-bench-leaderboard",
                  tracking_uri=tracking.uri)
    return ids


def view_metrics(doc: dict[str, Any]) -> list[str]:
    """The columns the UI's saved view shows: each split's dynamic minimum per front end (the first front end of the
    last split first: the sort key), then VO tracked and the decision time."""
    b = doc["benchmark"]
    splits = list(dict.fromkeys(r["split"] for r in doc["leaderboard"]))[::-1]
    out = [f"{s}.{fe}.dynamic_min" for s in splits for fe in b["frontends"]]
    out += [f"{s}.vo_tracked_rate" for s in splits] + ["controller_ms"]
    return out
