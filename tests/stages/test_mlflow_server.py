"""A real `mlflow server` on 127.0.0.1 serves the per-(controller, city) runs of a fixture-scale evaluation.

The server gets a free port, a temporary SQLite store and artifact directory, a bounded start-up wait, and is always
killed (its own process group) — also when the test fails.
"""

from __future__ import annotations

import json
import urllib.parse
import urllib.request

import mlflow
import pytest
from eval_fixtures import make_fixture_project, use_real_or_test_sensor

from expoctl.host import host_cpu
from tests.support.mlflow_ui import mlflow_server as support_mlflow_server


def _get(base: str, endpoint: str, **params) -> dict:
    url = f"{base}{endpoint}?{urllib.parse.urlencode(params)}" if params else f"{base}{endpoint}"
    with urllib.request.urlopen(url, timeout=30) as r:
        return json.loads(r.read().decode())


def _post(base: str, path: str, body: dict) -> dict:
    req = urllib.request.Request(f"{base}{path}", data=json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json"}, method="POST")
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.loads(r.read().decode())


@pytest.fixture()
def mlflow_server(tmp_path):
    """A real `mlflow server` on 127.0.0.1 over a store in tmp_path (tests/support/mlflow_ui.py); its base URL."""
    with support_mlflow_server(tmp_path) as base:
        yield base


def test_server_serves_one_run_per_controller_and_city(tmp_path, mlflow_server, monkeypatch):
    use_real_or_test_sensor(monkeypatch)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", mlflow_server)
    from stages import evaluate as stage
    from stages.tracking import tracked_run

    root = tmp_path / "proj"
    cfg = make_fixture_project(root, controllers=["agae", "oracle"])
    try:
        with tracked_run("evaluate", cfg) as tracker:
            stage.run(cfg, tracker, project_root=root)
            parent = tracker.run_id
    finally:
        mlflow.set_tracking_uri(None)
    metrics = json.loads((root / "reports/metrics.json").read_text())

    exp = _get(mlflow_server, "/api/2.0/mlflow/experiments/get-by-name", experiment_name="expoctl")["experiment"]
    found = _post(mlflow_server, "/api/2.0/mlflow/runs/search",
                  {"experiment_ids": [exp["experiment_id"]], "filter": "tags.stage = 'evaluate'", "max_results": 100})
    runs = found["runs"]
    children = [r for r in runs if any(t["key"] == "controller" for t in r["data"].get("tags", []))]
    tags = [{t["key"]: t["value"] for t in r["data"]["tags"]} for r in children]
    pairs = {(t["controller"], t["route_split"]) for t in tags}
    assert pairs == {(c, s) for c in ("agae", "oracle") for s in ("validation", "test")}
    assert all(t["mlflow.parentRunId"] == parent for t in tags)
    assert {t["city"] for t in tags} == {"validation", "test"}
    assert {t["host_cpu"] for t in tags} == {host_cpu()}  # per-frame timings name their machine, like the stage run
    for run, t in zip(children, tags):
        served = {m["key"]: m["value"] for m in run["data"]["metrics"]}
        expected = metrics[t["route_split"]][t["controller"]]
        for kind in ("static", "dynamic"):
            for fe in ("orb", "viso", "orb_sumlog", "viso_sumlog"):
                for stat in ("median_nfm", "min_nfm"):
                    assert served[f"{kind}.{fe}.{stat}"] == pytest.approx(expected[kind][fe][stat])
        assert served["tracking_success_n_runs"] == expected["tracking_success"][1]
        files = _get(mlflow_server, "/api/2.0/mlflow/artifacts/list", run_id=run["info"]["run_id"], path="figures")
        assert any(f["path"].endswith(".png") for f in files.get("files", [])), files
    # the experiment's saved view (what the UI opens: docs/pipeline.md#the-mlflow-ui) shows this run's children flat
    exp_tags = {t["key"]: t["value"] for t in exp.get("tags", [])}
    view = json.loads(json.loads(exp_tags["mlflow.sharedViewState.expoctl-compare-controllers"])["state"])
    assert view["searchFilter"] == f"tags.parent_stage_run = '{parent}'"
    assert "metrics.`dynamic.orb.min_nfm`" in view["selectedColumns"]
    assert exp_tags["mlflow.experimentKind"] == "custom_model_development"
    # the stage run itself carries the headline metrics and metrics.json
    stage_run = _get(mlflow_server, "/api/2.0/mlflow/runs/get", run_id=parent)["run"]
    assert {m["key"] for m in stage_run["data"]["metrics"]} >= {"n_runs", "validation.agae.tracking_success_rate"}
