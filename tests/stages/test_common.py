from __future__ import annotations

from pathlib import Path

import pytest

from expoctl.errors import InputError
from stages.common import config_hash, flatten, main_project_root, select_keys


def test_main_project_root_escapes_dvc_queue_copies():
    assert main_project_root(Path("/home/u/proj/.dvc/tmp/exps/tmpab12/")) == Path("/home/u/proj")
    assert main_project_root(Path("/home/u/proj")) == Path("/home/u/proj")


def test_select_keys_and_hash():
    cfg = {"a": {"b": 1, "c": [1, 2]}, "paths": {"x": "y"}}
    assert select_keys(cfg, ["a", "paths.x"]) == {"a": {"b": 1, "c": [1, 2]}, "paths.x": "y"}
    with pytest.raises(InputError, match="'paths.z' is missing"):
        select_keys(cfg, ["paths.z"])
    assert config_hash({"a": 1, "b": 2}) == config_hash({"b": 2, "a": 1}) != config_hash({"a": 2, "b": 2})


def test_flatten():
    assert flatten({"a": {"b": 1, "c": {"d": "x"}}, "l": [1, 2]}) == {"a.b": 1, "a.c.d": "x", "l": "[1, 2]"}


def test_tracked_run_logs_one_run_with_tags(tmp_path, monkeypatch):
    import mlflow

    from expoctl.host import host_cpu
    from stages import common

    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'm.db'}")
    cfg = {"ingest": {"image_width": 8}, "paths": {"raw_dir": "r", "frames": "f", "images_dir": "i"}, "scale_name": "fixture"}
    try:
        with common.tracked_run("ingest", cfg) as tracker:
            tracker.log_metrics({"n_images": 4, "nested": {"x": 1.5}})
        client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'm.db'}")
        (run,) = client.search_runs([client.get_experiment_by_name("expoctl").experiment_id])
        assert run.data.tags["stage"] == "ingest" and run.data.tags["scale"] == "fixture"
        assert run.data.tags["host_cpu"] == host_cpu()  # which machine made the run: numba compiles for its CPU
        assert run.data.tags["config_hash"] == common.config_hash(common.select_keys(cfg, common.STAGE_KEYS["ingest"]))
        assert run.data.params["ingest.image_width"] == "8"
        assert run.data.metrics["n_images"] == 4 and run.data.metrics["nested.x"] == 1.5
        assert "stage_seconds" in run.data.metrics
    finally:
        mlflow.set_tracking_uri(None)


def test_later_iterations_swap_paths_and_keep_the_earlier_ones():
    from stages.common import for_iteration, split_stage_name, stage_keys

    cfg = {"paths": {"raw_dir": "data/raw", "model": "models/controller.pt", "frames": "f.parquet"},
           "iteration2": {"enabled": True, "paths": {"raw_dir": "data/raw_iter2", "model": "models/c2.pt"}},
           "iteration3": {"enabled": False, "paths": {"raw_dir": "data/raw_iter3", "model": "models/c3.pt"}}}
    it2 = for_iteration(cfg, 2)
    assert it2["paths"] == {"raw_dir": "data/raw_iter2", "model": "models/c2.pt", "frames": "f.parquet"}
    assert it2["paths_prev"] == cfg["paths"] and it2["iteration"] == 2
    assert it2["raw_dirs_prev"] == ["data/raw"] and it2["iteration_block"] is cfg["iteration2"]
    it3 = for_iteration(cfg, 3)
    assert it3["paths"] == {"raw_dir": "data/raw_iter3", "model": "models/c3.pt", "frames": "f.parquet"}
    assert it3["paths_prev"] == it2["paths"]  # iteration 2's model is iteration 3's reference
    assert it3["raw_dirs_prev"] == ["data/raw", "data/raw_iter2"] and it3["iteration_block"]["enabled"] is False
    assert for_iteration(cfg, 1) is cfg
    assert split_stage_name("features_iter3") == ("features", 3) and split_stage_name("train") == ("train", 1)
    assert stage_keys("ingest_iter2") == stage_keys("ingest") + ["iteration2.enabled", "iteration2.paths"]
    assert stage_keys("ingest_iter3") == stage_keys("ingest") + ["iteration3.enabled", "iteration3.paths",
                                                                 "iteration2.paths"]
    assert "iteration2.collect" in stage_keys("collect_iter2") and "paths.model" in stage_keys("collect_iter2")
    assert "iteration3.collect" in stage_keys("collect_iter3") and "iteration2.paths" in stage_keys("collect_iter3")
    with pytest.raises(InputError, match="iteration2.paths"):
        for_iteration({"paths": {}}, 2)
    with pytest.raises(InputError, match="iteration3.paths"):
        for_iteration({k: v for k, v in cfg.items() if k != "iteration3"}, 3)
    with pytest.raises(InputError, match="--iteration"):
        for_iteration(cfg, 4)
