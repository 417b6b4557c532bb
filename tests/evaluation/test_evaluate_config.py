"""Config group `evaluate`: defaults load, bad values name their key."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from expoctl.errors import ConfigError
from expoctl.evaluation.runner import _windows_of
from expoctl.evaluation.config import EvaluateConfig, SplitPlan

ROOT = Path(__file__).resolve().parents[2]


def test_default_yaml_loads():
    cfg = EvaluateConfig.from_dict(yaml.safe_load((ROOT / "conf/evaluate/default.yaml").read_text()))
    assert set(cfg.splits) == {"validation", "test"}
    assert "oracle" in cfg.controllers and "learned" in cfg.controllers


@pytest.mark.parametrize("patch, key", [
    ({"controllers": ["agae", "nope"]}, "evaluate.controllers"),
    ({"controllers": ["agae", "agae"]}, "evaluate.controllers"),
    ({"splits": {"train": {}}}, "evaluate.splits.train"),
    ({"splits": {"test": {"window": "middle"}}}, "evaluate.splits.test.window"),
    ({"splits": {"test": {"windows": [-1]}}}, "evaluate.splits.test.windows"),
    ({"frontends": ["orb", "harris"]}, "evaluate.frontends"),  # a choice of registered front ends
    ({"render_size": [10, 10]}, "evaluate.render_size"),
    ({"vo": {"min_inliers": 3}}, "evaluate.vo.min_inliers"),
    ({"vo": {"map": {"min_inliers": 2}}}, "evaluate.vo.map.min_inliers"),
    ({"vo": {"map": {"search_radius_px": 0}}}, "evaluate.vo.map.search_radius_px"),
    ({"vo": {"map": {"radius": 15}}}, "evaluate.vo.map.radius"),
    ({"vo": {"map": [30]}}, "evaluate.vo.map"),
    ({"initial_exposure_us": 50.0}, "evaluate.initial_exposure_us"),
    ({"speed": 1}, "evaluate.speed"),
])
def test_bad_values_name_the_key(patch, key):
    d = {"splits": {"validation": {}}, **patch}
    with pytest.raises(ConfigError) as exc:
        EvaluateConfig.from_dict(d)
    assert exc.value.key == key


def test_windows_passage_and_portal_frames():
    portals = [(10.0, 0, "entry"), (16.0, 0, "exit"), (40.0, 1, "entry"), (41.0, 1, "exit")]
    passage = _windows_of(portals, SplitPlan("validation", before_s=2.0, after_s=1.0), 10.0, 600, warmup=5)
    assert passage == [("tunnel 0 passage", 80, 171), ("tunnel 1 passage", 380, 421)]
    portal = _windows_of(portals, SplitPlan("test", window="portal", before_s=1.0, after_s=1.0), 10.0, 600, warmup=5)
    assert [w[0] for w in portal] == ["tunnel 0 entry", "tunnel 0 exit", "tunnel 1 entry", "tunnel 1 exit"]
    assert portal[1][1:] == (150, 171)
    with pytest.raises(ConfigError, match="no room"):  # warm-up does not fit before the first entry
        _windows_of(portals, SplitPlan("test", before_s=2.0), 10.0, 600, warmup=90)


def test_vo_map_block_is_read():
    cfg = EvaluateConfig.from_dict({"splits": {"validation": {}}, "vo": {"map": {"min_inliers": 40,
                                                                                "search_radius_px": 10}}})
    assert cfg.vo.map.min_inliers == 40 and cfg.vo.map.search_radius_px == 10.0
    assert cfg.vo.map.keyframe_every == 5  # unset keys keep the module's defaults
    assert cfg.vo.map.n_features == cfg.vo.n_features == 2000  # one ORB budget for both trackers
    assert hash(cfg.vo)  # frozen all the way down


def test_frontends_and_controllers_are_choices_of_the_registries():
    """null (or absent) is every registered one but the opt-in `rl`, in table order; a subset is kept as given."""
    from expoctl.controllers.registry import CONTROLLERS, controller_names
    from expoctl.features.registry import FRONTENDS

    every = EvaluateConfig.from_dict({"splits": {"validation": {}}, "controllers": None, "frontends": None})
    assert every.controllers == controller_names() == tuple(n for n in CONTROLLERS.names() if n != "rl")
    assert every.frontends == FRONTENDS.names() == ("orb", "viso")
    assert every.controllers[:2] == ("agae", "shin") and every.controllers[-2:] == ("learned", "oracle")
    one = EvaluateConfig.from_dict({"splits": {"validation": {}}, "controllers": ["agae"], "frontends": ["viso"]})
    assert one.controllers == ("agae",) and one.frontends == ("viso",)
