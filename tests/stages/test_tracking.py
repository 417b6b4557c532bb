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
    from expoctl.numerics import NumericsConfig, record

    cfg = {"ingest": {"image_width": 8}, "paths": {"raw_dir": "r", "frames": "f", "images_dir": "i"},
           "scale_name": "fixture", "numerics": {"mode": "pinned"}}
    try:
        with tracked_run("ingest", cfg, record(NumericsConfig("pinned"), ["torch"])) as tracker:
            tracker.log_metrics({"n_images": 4, "nested": {"x": 1.5}})
        client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'm.db'}")
        (run,) = client.search_runs([client.get_experiment_by_name("expoctl").experiment_id])
        assert run.data.tags["stage"] == "ingest" and run.data.tags["scale"] == "fixture"
        assert run.data.tags["host_cpu"] == host_cpu()  # which machine made the run: numba compiles for its CPU
        assert run.data.tags["config_hash"] == config_hash(select_keys(cfg, STAGE_KEYS["ingest"]))
        assert run.data.params["ingest.image_width"] == "8"
        assert run.data.metrics["n_images"] == 4 and run.data.metrics["nested.x"] == 1.5
        assert "stage_seconds" in run.data.metrics
        # which numeric mode, and whether it came in time (here: torch was imported before it was applied)
        assert run.data.params["numerics.mode"] == "pinned" and run.data.tags["numerics.mode"] == "pinned"
        assert run.data.tags["numerics.applied_before_import"] == "False"
        assert "numpy " in run.data.tags["numerics.versions"]
    finally:
        mlflow.set_tracking_uri(None)


def test_runtime_keys_are_logged_but_not_hashed(tmp_path, monkeypatch):
    """`parallel` only chooses where features' jobs run: its run logs it, its config_hash (like its DVC params)
    leaves it out, so a Ray run and a local one of the same config carry the same hash."""
    import mlflow

    from stages.keys import STAGE_KEYS, config_hash, runtime_keys, select_keys
    from stages.tracking import tracked_run

    assert runtime_keys("features") == ["parallel"] and "parallel" not in STAGE_KEYS["features"]
    assert runtime_keys("features_iter@2") == ["parallel"] and runtime_keys("train") == []
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'm.db'}")
    base = {"features": {"seed": 0}, "plugins": {"frontends": {}}, "numerics": {"mode": "host"},
            "paths": {"frames": "f", "features": "x", "matches": "m"}}
    try:
        for backend in ("processes", "ray"):
            with tracked_run("features", {**base, "parallel": {"backend": backend, "address": "h:1",
                                                                "n_jobs": 1 if backend == "ray" else 2}}):
                pass
        client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'm.db'}")
        runs = client.search_runs([client.get_experiment_by_name("expoctl").experiment_id])
        assert sorted(r.data.params["parallel.backend"] for r in runs) == ["processes", "ray"]
        assert sorted(r.data.params["parallel.n_jobs"] for r in runs) == ["1", "2"]  # logged, not hashed
        assert {r.data.tags["config_hash"] for r in runs} == {config_hash(select_keys(base, STAGE_KEYS["features"]))}
    finally:
        mlflow.set_tracking_uri(None)
