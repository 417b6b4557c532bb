from __future__ import annotations

import contextlib
from pathlib import Path

import pytest
import yaml

from expoctl.errors import InputError
from fake_tracker import FakeTracker
from stages import compose as stage
from stages.compose import compose_config, read_params

UNKNOWN_CITY = ("unknown city 'nowhere'; known cities: train, validation, test, stress, ramp_tunnel, underpass "
                "(or pass a dict)")
TRAIN_KEY = ("params.yaml: key 'train' is not an expoctl setting: put Hydra overrides in the 'overrides' list, "
             "e.g. dvc exp run -S 'overrides=[\"train.lr=0.001\"]'")


def test_overrides_apply_and_resolve():
    cfg = compose_config(["scale=fixture", "ingest.image_width=32", "seed=7"])
    assert cfg["ingest"]["image_width"] == 32 and cfg["seed"] == 7 and cfg["scale_name"] == "fixture"
    assert cfg["paths"]["frames"] == "data/frames.parquet"


@pytest.mark.parametrize("overrides,words", [
    (["scale=huge"], "scale"),
    (["ingest.no_such_key=1"], "no_such_key"),
    ("scale=fixture", "must be a list of strings"),
])
def test_bad_overrides_name_the_problem(overrides, words):
    with pytest.raises(InputError, match=words):
        compose_config(overrides)


@pytest.mark.parametrize("text,overrides,problems", [
    ("overrides: [scale=fixture]\n", ["scale=fixture"], []),
    ("", [], []),
    ("overrides: null\n", [], []),
    # what `dvc exp run -S train.lr=1e-3` (or -S +train.lr=1e-3) writes
    ("overrides: []\ntrain:\n  lr: 0.001\n", [], [TRAIN_KEY]),
    ("note: hello\n", [], ["params.yaml: key 'note' is not an expoctl setting: put Hydra overrides in the "
                           "'overrides' list, e.g. dvc exp run -S 'overrides=[\"note=hello\"]'"]),
    ("overrides: scale=fixture\n", None, ["params.yaml: key 'overrides' must be a list of strings, got "
                                          "'scale=fixture'"]),
    ("- scale=fixture\n", None, ["params.yaml: must be a mapping with one key, 'overrides' (a list of Hydra "
                                 "overrides), got ['scale=fixture']"]),
    ("overrides: [a\n", None, ["params.yaml: not valid YAML (line 2, column 1: expected ',' or ']', but got "
                               "'<stream end>')"]),
])
def test_read_params(tmp_path, text, overrides, problems):
    (tmp_path / "params.yaml").write_text(text)
    assert read_params(tmp_path / "params.yaml") == (overrides, problems)


@pytest.fixture
def project(tmp_path, monkeypatch):
    """compose's params.yaml and resolved.yaml in a tmp dir, an earlier resolved.yaml in place, and no MLflow: the
    run is a FakeTracker (recorded in `tracked`)."""
    resolved = tmp_path / "configs" / "resolved.yaml"
    resolved.parent.mkdir()
    resolved.write_bytes(b"# an earlier, good resolved config\nseed: 0\n")
    monkeypatch.setattr(stage, "PARAMS", tmp_path / "params.yaml")
    monkeypatch.setattr(stage, "RESOLVED_CONFIG", resolved)
    tracked = []

    @contextlib.contextmanager
    def fake_run(name, cfg):
        tracked.append(FakeTracker())
        yield tracked[-1]

    monkeypatch.setattr(stage, "tracked_run", fake_run)
    return tmp_path, resolved, tracked


def run_main(params: str, project) -> int:
    """compose's main on this params.yaml text; its exit code."""
    tmp_path, _, _ = project
    (tmp_path / "params.yaml").write_text(params)
    try:
        stage.main()
    except SystemExit as exc:
        return exc.code
    return 0


def test_good_params_write_resolved_config(project, capsys):
    _, resolved, tracked = project
    assert run_main("overrides: [scale=fixture, train.lr=3.0e-4]\n", project) == 0
    text = resolved.read_text()
    assert text.startswith(stage.HEADER)
    cfg = yaml.safe_load(text)
    assert cfg["train"]["lr"] == 3e-4 and cfg["scale_name"] == "fixture"
    assert tracked[0].params == {"overrides": ["scale=fixture", "train.lr=3.0e-4"]}
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("params,errors", [
    ("overrides: [train.lr=abc]\n", ["config key 'train.lr': must be a finite number, got 'abc'"]),
    ("overrides: [train.lr=-1]\n", ["config key 'train.lr': must be > 0, got -1.0"]),
    ("overrides: [world.render.width=0]\n",
     ["config key 'world.render.width': must be an integer in [16, 8192] pixels, got 0"]),
    ("overrides: [world.cities.test=nowhere]\n", [f"config key 'world.cities.test': {UNKNOWN_CITY}"]),
    ("overrides: [+unused_note=hello]\n", [
        "config key 'unused_note': unknown key (expected one of ['collect', 'controllers', 'evaluate', 'features', "
        "'ingest', 'iteration2', 'iteration3', 'labels', 'model', 'numerics', 'parallel', 'paths', 'report', 'rig', 'rl', "
        "'samples', 'scale_name', 'seed', 'select_model', 'sensor', 'train', 'world'])"]),
    ("overrides: [scale=huge]\n", ["params.yaml overrides ['scale=huge']: In 'config': Could not find "
                                   "'scale/huge'"]),
    # params.yaml's own problems and the config's, in one run
    ("overrides: [train.lr=abc, world.render.width=0, world.cities.test=nowhere]\ntrain:\n  lr: 0.001\n", [
        TRAIN_KEY,
        "config key 'world.render.width': must be an integer in [16, 8192] pixels, got 0",
        "config key 'train.lr': must be a finite number, got 'abc'",
        f"config key 'world.cities.test': {UNKNOWN_CITY}"]),
    ("[scale=fixture]\n", ["params.yaml: must be a mapping with one key, 'overrides' (a list of Hydra overrides), "
                           "got ['scale=fixture']"]),
])
def test_a_problem_exits_2_naming_every_problem_and_keeps_the_previous_resolved_config(project, capsys, params,
                                                                                       errors):
    _, resolved, tracked = project
    before = resolved.read_bytes()
    assert run_main(params, project) == 2
    assert capsys.readouterr().err.splitlines() == [f"expoctl compose: error: {e}" for e in errors]
    assert resolved.read_bytes() == before  # untouched, byte for byte
    assert [p.name for p in resolved.parent.iterdir()] == ["resolved.yaml"]  # no temporary left beside it
    assert tracked == []  # no MLflow run was opened


def test_project_params_compose_and_pass():
    """The repository's own params.yaml is valid."""
    overrides, problems = read_params(Path(stage.PROJECT_ROOT) / "params.yaml")
    assert problems == []
    from stages.config_check import check_resolved

    check_resolved(compose_config(overrides))
