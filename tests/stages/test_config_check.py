"""check_resolved: every stage's config groups checked at compose time, every problem named by its dotted key."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from expoctl.errors import ConfigError
from stages.compose import compose_config
from stages.config_check import PATH_KEYS, TOP_LEVEL_KEYS, check_resolved

CONF = Path(__file__).resolve().parents[2] / "conf"
TOP_LEVEL = sorted(TOP_LEVEL_KEYS)
UNKNOWN_CITY = ("unknown city 'nowhere'; known cities: train, validation, test, stress, ramp_tunnel, underpass "
                "(or pass a dict)")


def problems_of(overrides: list[str]) -> list[tuple[str, str]]:
    with pytest.raises(ConfigError) as exc:
        check_resolved(compose_config(overrides))
    return exc.value.problems


@pytest.mark.parametrize("scale", ["fixture", "default", "paper"])
def test_every_scale_preset_passes(scale):
    check_resolved(compose_config([f"scale={scale}"]))


@pytest.mark.parametrize("overrides,problems", [
    (["train.lr=abc"], [("train.lr", "must be a finite number, got 'abc'")]),
    (["train.lr=-1"], [("train.lr", "must be > 0, got -1.0")]),
    (["world.render.width=0"], [("world.render.width", "must be an integer in [16, 8192] pixels, got 0")]),
    (["world.cities.test=nowhere"], [("world.cities.test", UNKNOWN_CITY)]),
    (["+unused_note=hello"], [("unused_note", f"unknown key (expected one of {TOP_LEVEL})")]),
    (["model.dropout=1.5"], [("model.dropout", "must be in [0, 1), got 1.5")]),
    (["labels.window=0"], [("labels.window", "must be an integer >= 1, got 0")]),
    (["samples.metric=best"], [("samples.metric", "must be one of feat, match, hybrid, got 'best'")]),
    (["ingest.image_width=4"], [("ingest.image_width", "must be an integer in [8, 4096] pixels, got 4")]),
    (["features.orb.scale_factor=1"], [("features.orb.scale_factor", "must be a number > 1, got 1")]),
    (["+features.viso.nms_n=0"], [("features.viso.nms_n", "must be an integer >= 1, got 0")]),
    (["report.strip_columns=0"], [("report.strip_columns", "must be an integer in [1, 20], got 0")]),
    (["select_model.probe.city=test"], [("select_model.probe.city",
                                         "'test' is the held-out city (use train or validation)")]),
    (["evaluate.sumlog_pairs=0"], [("evaluate.sumlog_pairs", "must be an integer >= 1, got 0")]),
    (["controllers.shin.alpha=2"], [("controllers.shin.alpha", "must be in [0, 1]")]),
    (["+controllers.oracle.match_width=8"], [("controllers.oracle.match_width", "must be an integer >= 32, got 8")]),
    (["+controllers.learned.backend=tensorrt"], [("controllers.learned.backend",
                                                   "must be one of torch, onnx, got 'tensorrt'")]),
    (["collect.reference_controller=auto"], [("collect.reference_controller",
                                               "unknown controller 'auto' (known: agae, shin, shim, "
                                               "mean_intensity, fixed, learned)")]),
    (["collect.reference_controller=oracle"], [("collect.reference_controller",
                                                 "'oracle' cannot drive collect (it renders candidate frames from "
                                                 "the simulator's scene, which only evaluate gives it); use one of: "
                                                 "agae, shin, shim, mean_intensity, fixed, learned")]),
    (["seed=-1"], [("seed", "must be an integer >= 0, got -1")]),
    (["paths.frames=null"], [("paths.frames", "must be a non-empty string, got None")]),
])
def test_bad_value_is_named_by_its_key(overrides, problems):
    assert problems_of(overrides) == problems


def test_several_bad_values_are_all_reported_at_once():
    assert problems_of(["train.lr=abc", "model.dropout=2", "world.render.width=0", "world.cities.test=nowhere",
                        "collect.warmup_frames=-2", "+unused_note=hello"]) == [
        ("collect.warmup_frames", "must be an integer >= 0, got -2"),
        ("world.render.width", "must be an integer in [16, 8192] pixels, got 0"),
        ("model.dropout", "must be in [0, 1), got 2.0"),
        ("train.lr", "must be a finite number, got 'abc'"),
        ("world.cities.test", UNKNOWN_CITY),
        ("unused_note", f"unknown key (expected one of {TOP_LEVEL})"),
    ]


def test_a_group_several_stages_read_is_reported_once():
    # world, rig and sensor are read by collect, evaluate and select_model alike
    assert problems_of(["rig.fps=0"]) == [("rig.fps", "must be a number > 0, got 0")]


@pytest.mark.parametrize("overrides,problems", [
    (["iteration2.reference_gate=maybe"], [("iteration2.reference_gate", "must be one of probe, none, got 'maybe'")]),
    (["iteration3.enabled=1"], [("iteration3.enabled", "must be true or false, got 1")]),
    (["iteration2.paths.model=3"], [("iteration2.paths.model", "must be a non-empty string, got 3")]),
    (["+iteration2.paths.final_model=m.pt"], [("iteration2.paths.final_model", "unknown key (expected one of "
                                               f"{sorted(k for k in PATH_KEYS if k != 'final_model')})")]),
    # the iteration's collect block merged over `collect` is a collect config; a disabled iteration's too
    (["+iteration2.collect.warmup_frames=-1"], [("iteration2.collect.warmup_frames",
                                                  "must be an integer >= 0, got -1")]),
    (["iteration3.collect.splits.train.first_traversal=abc"], [
        ("iteration3.collect.splits.train.first_traversal", "must be an integer >= 0, got 'abc'")]),
    (["iteration2.collect.reference_controller=auto"], [
        ("iteration2.collect.reference_controller", "unknown controller 'auto' (known: agae, shin, shim, "
                                                    "mean_intensity, fixed, learned)")]),
])
def test_later_iteration_blocks_are_checked(overrides, problems):
    assert problems_of(overrides) == problems


def test_a_base_collect_problem_is_not_repeated_under_each_iteration():
    assert problems_of(["collect.warmup_frames=-1"]) == [("collect.warmup_frames", "must be an integer >= 0, got -1")]


@pytest.mark.parametrize("group", ["collect", "features", "evaluate"])
def test_a_stage_worker_count_is_refused_with_where_it_moved(group):
    """`<group>.n_jobs` became `parallel.n_jobs` (2026-12-07): one worker count, a runtime setting, not a param."""
    from expoctl.parallel import MOVED_N_JOBS

    assert problems_of([f"+{group}.n_jobs=2"]) == [(f"{group}.n_jobs", f"moved to parallel.n_jobs ({MOVED_N_JOBS})")]


@pytest.mark.parametrize("value", ["0", "-2", "two"])
def test_parallel_n_jobs_is_checked(value):
    assert problems_of([f"parallel.n_jobs={value}"]) == [
        ("parallel.n_jobs", f"must be a positive integer or -1 (one worker per core), got {yaml.safe_load(value)!r}")]


def test_cities_a_stage_asks_for_must_be_configured():
    assert problems_of(["~world.cities.test"]) == [
        ("world.cities.test", "missing: evaluate.splits.test needs a city"),
        ("world.cities.test", "missing: collect.splits.test asks for 2 sequences"),
    ]
    assert problems_of(["select_model.enabled=true", "select_model.city=paris"]) == [
        ("select_model.city", "'paris' is not a world.cities entry (['stress', 'test', 'train', 'validation'])"),
    ]


def test_scenario_city_from_city_dir_passes():
    check_resolved(compose_config(["world.cities.test=underpass", "+world.cities.extra=ramp_tunnel"]))


def test_no_checkpoint_or_data_is_needed(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no data/ or models/ under the working directory either
    check_resolved(compose_config([f"+controllers.learned.checkpoint={tmp_path}/missing.pt"]))


def test_top_level_keys_are_conf_config_and_scale_presets():
    config = yaml.safe_load((CONF / "config.yaml").read_text())
    groups = [next(iter(d)) for d in config["defaults"] if isinstance(d, dict) and next(iter(d)) != "scale"]
    presets = set()
    for preset in (CONF / "scale").glob("*.yaml"):
        presets |= set(yaml.safe_load(preset.read_text()))
    expected = set(groups) | (set(config) - {"defaults"}) | presets
    assert sorted(TOP_LEVEL_KEYS) == sorted(expected)
    assert sorted(PATH_KEYS) == sorted(config["paths"])


@pytest.mark.parametrize("override,key", [
    ("paths.raw_dir=data/rig", "paths.raw_dir"),
    ("iteration2.paths.model=models/other.pt", "iteration2.paths.model"),
])
def test_output_paths_are_fixed_by_dvc_yaml(override, key):
    """The old docs' `paths.raw_dir=data/rig` would have collect replace data/rig (a user's recordings) whole."""
    from stages.compose import compose_config

    with pytest.raises(ConfigError) as exc:
        check_resolved(compose_config(["scale=fixture", override]))
    assert [k for k, _ in exc.value.problems] == [key]
    assert "fixed by dvc.yaml" in str(exc.value) and "data/recordings" in str(exc.value)
