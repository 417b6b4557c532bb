from __future__ import annotations

from stages.tracking import flatten


def test_flatten():
    assert flatten({"a": {"b": 1, "c": {"d": "x"}}, "l": [1, 2]}) == {"a.b": 1, "a.c.d": "x", "l": "[1, 2]"}


def test_tracked_run_logs_one_run_with_tags(tmp_path, monkeypatch):
    import mlflow

    from expoctl.host import host_cpu
    from stages.keys import STAGE_KEYS, config_hash, select_keys
    from stages.tracking import tracked_run

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'm.db'}")
    cfg = {"ingest": {"image_width": 8}, "paths": {"raw_dir": "r", "frames": "f", "images_dir": "i"}, "scale_name": "fixture"}
    try:
        with tracked_run("ingest", cfg) as tracker:
            tracker.log_metrics({"n_images": 4, "nested": {"x": 1.5}})
        client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'm.db'}")
        (run,) = client.search_runs([client.get_experiment_by_name("expoctl").experiment_id])
        assert run.data.tags["stage"] == "ingest" and run.data.tags["scale"] == "fixture"
        assert run.data.tags["host_cpu"] == host_cpu()  # which machine made the run: numba compiles for its CPU
        assert run.data.tags["config_hash"] == config_hash(select_keys(cfg, STAGE_KEYS["ingest"]))
        assert run.data.params["ingest.image_width"] == "8"
        assert run.data.metrics["n_images"] == 4 and run.data.metrics["nested.x"] == 1.5
        assert "stage_seconds" in run.data.metrics
    finally:
        mlflow.set_tracking_uri(None)
