"""The pipeline's MLflow experiment is set up to open in the UI on the runs table with the leaderboard columns
(expoctl.tracking_ui, stages/tracking.py): the tags the UI reads, checked without a browser
(tests/stages/test_mlflow_ui_browser.py checks what a browser shows)."""

from __future__ import annotations

import json

import mlflow
import pytest

from expoctl import tracking_ui


@pytest.fixture()
def store(tmp_path, monkeypatch):
    uri = f"sqlite:///{tmp_path / 'm.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    yield uri
    mlflow.set_tracking_uri(None)


def _view(tags: dict) -> tuple[dict, dict]:
    envelope = json.loads(tags[tracking_ui.VIEW_TAG_PREFIX + tracking_ui.VIEW_ID])
    return envelope, json.loads(envelope["state"])


def test_init_tracking_sets_the_runs_view(store):
    from stages.tracking import LEADERBOARD_METRICS, init_tracking

    exp_id = init_tracking()
    tags = mlflow.MlflowClient(store).get_experiment(exp_id).tags
    assert tags["mlflow.experimentKind"] == "custom_model_development"
    envelope, state = _view(tags)
    assert envelope["name"] == "Compare controllers" and isinstance(envelope["createdAt"], int)
    metric_cols = [f"metrics.`{m}`" for m in LEADERBOARD_METRICS]
    assert state["selectedColumns"] == metric_cols
    assert state["columnOrder"] == metric_cols and set(state["columnWidths"]) == set(metric_cols)
    assert state["orderByKey"] == "metrics.`dynamic.orb.min_nfm`" and state["orderByAsc"] is False
    assert state["searchFilter"] == ""
    path = f"#/experiments/{exp_id}/runs?viewStateShareKey={tracking_ui.VIEW_ID}&workflowType=machine_learning"
    assert f"]({path})" in tags["mlflow.note.content"]  # the description links to the view
    assert tags["mlflow.experiment.primaryMetric.name"] == "dynamic.orb.min_nfm"


def test_an_existing_experiment_is_updated_and_a_persons_description_kept(store):
    from stages.tracking import init_tracking

    client = mlflow.MlflowClient(store)
    exp_id = client.create_experiment("expoctl")  # as stores made before this change have it
    client.set_experiment_tag(exp_id, "mlflow.note.content", "my notes")
    assert init_tracking() == exp_id
    tags = client.get_experiment(exp_id).tags
    assert tags["mlflow.experimentKind"] == "custom_model_development"
    assert _view(tags)[1]["selectedColumns"]
    assert tags["mlflow.note.content"] == "my notes"


def test_the_evaluate_filter_survives_later_stages_and_unchanged_tags_are_not_rewritten(store, monkeypatch):
    from stages.tracking import init_tracking, set_compare_view

    exp_id = init_tracking()
    set_compare_view(exp_id, evaluate_run="abc123")
    client = mlflow.MlflowClient(store)
    created = _view(client.get_experiment(exp_id).tags)[0]["createdAt"]
    writes = []
    real = mlflow.MlflowClient.set_experiment_tag
    monkeypatch.setattr(mlflow.MlflowClient, "set_experiment_tag",
                        lambda self, *a, **k: (writes.append(a[1]), real(self, *a, **k)))
    init_tracking()  # every stage run calls it: it must keep the evaluate run's filter and write nothing
    envelope, state = _view(client.get_experiment(exp_id).tags)
    assert state["searchFilter"] == "tags.parent_stage_run = 'abc123'"
    assert writes == []
    set_compare_view(exp_id, evaluate_run="def456")
    envelope, state = _view(client.get_experiment(exp_id).tags)
    assert writes == [tracking_ui.VIEW_TAG_PREFIX + tracking_ui.VIEW_ID]
    assert state["searchFilter"] == "tags.parent_stage_run = 'def456'" and envelope["createdAt"] == created


def test_view_state_columns_and_keys():
    state = tracking_ui.view_state(metrics=["validation.dynamic.orb.min_nfm"], tags=["controller"],
                                   order_by="validation.dynamic.orb.min_nfm", ascending=True,
                                   search_filter="tags.bench_id = 'x'")
    assert state["selectedColumns"] == ["tags.`controller`", "metrics.`validation.dynamic.orb.min_nfm`"]
    assert state["orderByAsc"] is True and state["searchFilter"] == "tags.bench_id = 'x'"
    with pytest.raises(ValueError):
        tracking_ui.column_key("metric", "x")
