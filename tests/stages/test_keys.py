from __future__ import annotations

import pytest

from expoctl.errors import InputError
from stages.keys import config_hash, select_keys, split_stage_name, stage_keys, stage_name


def test_select_keys_and_hash():
    cfg = {"a": {"b": 1, "c": [1, 2]}, "paths": {"x": "y"}}
    assert select_keys(cfg, ["a", "paths.x"]) == {"a": {"b": 1, "c": [1, 2]}, "paths.x": "y"}
    with pytest.raises(InputError, match="'paths.z' is missing"):
        select_keys(cfg, ["paths.z"])
    assert config_hash({"a": 1, "b": 2}) == config_hash({"b": 2, "a": 1}) != config_hash({"a": 2, "b": 2})


def test_stage_names_round_trip_dvc_foreach_names():
    assert stage_name("features", 1) == "features" and stage_name("features", 3) == "features_iter@3"
    assert split_stage_name("features_iter@3") == ("features", 3) and split_stage_name("train") == ("train", 1)
    assert split_stage_name("collect_iter@2") == ("collect", 2)
    for base in ("collect", "select_model", "train"):
        for n in (1, 2, 3):
            assert split_stage_name(stage_name(base, n)) == (base, n)


def test_later_iterations_read_their_block_and_every_earlier_iterations_paths():
    assert stage_keys("ingest_iter@2") == stage_keys("ingest") + ["iteration2.enabled", "iteration2.paths"]
    assert stage_keys("ingest_iter@3") == stage_keys("ingest") + ["iteration3.enabled", "iteration3.paths",
                                                                  "iteration2.paths"]
    assert "iteration2.collect" in stage_keys("collect_iter@2") and "paths.model" in stage_keys("collect_iter@2")
    assert "iteration3.collect" in stage_keys("collect_iter@3") and "iteration2.paths" in stage_keys("collect_iter@3")
    # the reference gate: its own key and the probe's test it runs on the previous network
    assert {"iteration2.reference_gate", "select_model.probe"} <= set(stage_keys("collect_iter@2"))
    assert "iteration3.reference_gate" in stage_keys("collect_iter@3")
    assert stage_keys("no_such_stage") == []


def test_collect_reads_the_sections_compose_copies_for_it():
    """collect's controller sections are declared through `collect_controllers.iteration<N>` (which compose derives
    from collect's reference controller), not a fixed `controllers.agae`."""
    assert "collect_controllers.iteration1" in stage_keys("collect")
    assert not any(k.startswith("controllers") for k in stage_keys("collect"))
    for n in (2, 3):
        keys = stage_keys(f"collect_iter@{n}")
        assert f"collect_controllers.iteration{n}" in keys and "collect_controllers.iteration1" not in keys
        assert not any(k.startswith("controllers") for k in keys)
    # every other stage's keys are as before the table: evaluate and select_model read all of `controllers`
    assert "controllers" in stage_keys("evaluate") and "controllers" in stage_keys("select_model")
    assert len(stage_keys("collect_iter@3")) == len(set(stage_keys("collect_iter@3")))  # each key once
