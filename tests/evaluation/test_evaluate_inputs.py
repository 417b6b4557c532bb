"""EvaluationInputs: the typed config evaluation reads, built once by the stage and handed to workers as is."""

from __future__ import annotations

import copy
import pickle

import pytest

from expoctl.errors import ConfigError
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.world import RenderConfig

CFG = {
    "seed": 4,
    "sensor": {},
    "rig": {"fps": 10.0},
    "world": {"cities": {"validation": "validation", "test": "test"}, "city_dir": "conf/world/cities",
              "render": {"width": 96, "height": 72, "hfov_deg": 70.0}},
    "controllers": {"fixed": {"mode": "manual"}, "learned": {"latency_frames": 1}},
    "features": {},
    "evaluate": {"controllers": ["fixed", "learned"], "splits": {"validation": {}}, "render_size": [64, 48]},
    "paths": {"frames": "data/frames.parquet", "model": "models/controller.pt"},
}


def test_built_once_and_picklable_for_the_workers():
    inputs = EvaluationInputs.from_resolved(CFG)
    assert (inputs.seed, inputs.rig.fps, inputs.evaluate.controllers) == (4, 10.0, ("fixed", "learned"))
    assert inputs.world.render == RenderConfig(width=96, height=72, hfov_deg=70.0)
    assert (inputs.render.width, inputs.render.height, inputs.render.hfov_deg) == (64, 48, 70.0)  # render_size
    assert inputs.frames_path == "data/frames.parquet" and inputs.model_path == "models/controller.pt"
    # typed once here: the workers get configs, never a dict to parse again
    from expoctl.controllers.fixed import FixedConfig
    from expoctl.controllers.shin import ShinConfig

    assert inputs.controller_config("fixed") == FixedConfig(mode="manual")
    assert inputs.controller_config("shin") == ShinConfig()  # no section: the defaults
    assert set(inputs.controllers) == {"fixed", "learned"}
    assert pickle.loads(pickle.dumps(inputs)) == inputs
    with pytest.raises(AttributeError):  # frozen: a worker cannot change what the stage built
        inputs.seed = 5


def test_the_checkpoint_key_overrides_paths_model(tmp_path):
    cfg = copy.deepcopy(CFG)
    cfg["controllers"]["learned"]["checkpoint"] = "/abs/net.pt"
    inputs = EvaluationInputs.from_resolved(cfg)
    assert inputs.learned_model_path(tmp_path).as_posix() == "/abs/net.pt"
    assert EvaluationInputs.from_resolved(CFG).learned_model_path(tmp_path) == tmp_path / "models/controller.pt"


def test_every_group_problem_in_one_pass():
    cfg = copy.deepcopy(CFG)
    cfg["evaluate"]["warmup_frames"] = -1
    cfg["features"]["n_jobs"] = 0
    cfg["seed"] = "x"
    cfg["world"]["render"]["hfov_deg"] = 180
    cfg["rig"]["fps"] = 0
    cfg["sensor"] = {"full_well_e": -5.0}
    cfg["controllers"]["shin"] = 3
    with pytest.raises(ConfigError) as exc:
        EvaluationInputs.from_resolved(cfg)
    assert [k for k, _ in exc.value.problems] == [
        "evaluate.warmup_frames", "features.n_jobs", "seed", "world.render.hfov_deg", "rig.fps", "sensor.full_well_e",
        "controllers.shin"]
    assert exc.value.problems[3] == ("world.render.hfov_deg", "must be a number in (0.0, 180.0) degrees, got 180")


def test_every_controller_section_is_checked_and_an_unknown_one_is_named():
    cfg = copy.deepcopy(CFG)
    cfg["controllers"]["shin"] = {"alpha": 2.0}  # not driven by evaluate, still checked
    cfg["controllers"]["hold"] = {"gain_db": 1.0}  # no such controller installed
    with pytest.raises(ConfigError) as exc:
        EvaluationInputs.from_resolved(cfg)
    keys = [k for k, _ in exc.value.problems]
    assert keys == ["controllers.shin.alpha", "controllers.hold"]
    assert "unknown controller 'hold'" in exc.value.problems[1][1] and "expoctl.controllers" in exc.value.problems[1][1]
