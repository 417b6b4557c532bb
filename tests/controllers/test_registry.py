"""Registry: names build the right controllers from their config sections; the YAML defaults are valid."""

from pathlib import Path

import numpy as np
import pytest

from expoctl.controllers.base import Controller, Settings
from dataclasses import dataclass

from expoctl.controllers.registry import CONTROLLERS, ControllerContext, make_controller, register_controller
from expoctl.errors import ConfigError

CONF = Path(__file__).resolve().parents[2] / "conf" / "controllers" / "default.yaml"
# built from their YAML section alone; learned and oracle register themselves later and need runtime inputs
BASELINES = ["agae", "fixed", "mean_intensity", "shim", "shin"]


def _conf() -> dict:
    """The controllers group as the stages see it: composed, interpolations (e.g. ${sensor.response_curve}) resolved."""
    from stages.compose import compose_config

    return compose_config([])["controllers"]


@pytest.mark.parametrize("name", BASELINES)
def test_every_baseline_builds_from_the_yaml_and_runs(name):
    cfg = _conf()
    ctrl = make_controller(name, cfg.get(name, {}))
    assert isinstance(ctrl, Controller) and ctrl.name == name
    ctrl.reset(Settings(0.0, 5000.0))
    s = Settings(0.0, 5000.0)
    for code in (0, 255, 128):
        s = ctrl.update(np.full((32, 32, 3), code, np.uint8), s)
        assert np.isfinite([s.gain_db, s.exposure_us]).all() and s == s.clamped()


def test_every_baseline_is_registered_and_has_a_yaml_section():
    assert set(BASELINES) <= set(CONTROLLERS) and set(BASELINES) <= set(_conf())


def test_unknown_name_and_unknown_key():
    with pytest.raises(ConfigError):
        make_controller("autoexposure", {})
    with pytest.raises(ConfigError) as e:
        make_controller("agae", {"bogus": 1})
    assert e.value.key == "controllers.agae.bogus"


@dataclass(frozen=True)
class _HoldConfig:
    gain_db: float = 3.0


def test_register_extends_the_registry_with_a_typed_config():
    class Hold(Controller):
        name = "hold_test"

        def __init__(self, config):
            self.config = config

        def reset(self, initial):
            self.s = initial

        def update(self, image, applied):
            return Settings(self.config.gain_db, applied.exposure_us)

    register_controller("hold_test", config=_HoldConfig, label="Hold", rank=55)(Hold)
    try:
        assert CONTROLLERS.names().index("hold_test") == CONTROLLERS.names().index("fixed") + 1  # rank 55
        ctrl = make_controller("hold_test", {"gain_db": 6})
        assert ctrl.config == _HoldConfig(6.0) and ctrl.update(None, Settings(0.0, 100.0)) == Settings(6.0, 100.0)
        with pytest.raises(ConfigError) as e:
            make_controller("hold_test", {"gain_db": "x", "gian_db": 1})
        assert [k for k, _ in e.value.problems] == ["controllers.hold_test.gain_db", "controllers.hold_test.gian_db"]
        entry = CONTROLLERS.get("hold_test")
        assert entry.module == __name__ and entry.package != "expoctl" and entry.label == "Hold"
    finally:
        CONTROLLERS.unregister("hold_test")
    assert "hold_test" not in CONTROLLERS


def test_a_class_without_the_methods_or_an_untyped_config_is_refused():
    class NoUpdate:
        def reset(self, initial):
            pass

    """Outside expoctl a broken registration is kept as broken (named with its package), never half-registered."""
    CONTROLLERS.register("no_update_test", config=_HoldConfig, needs=())(NoUpdate)
    CONTROLLERS.register("dict_config_test", config=dict, needs=())(Hold2)
    try:
        broken = CONTROLLERS.broken()
        assert "lacks the method(s) update" in broken["no_update_test"][1]
        assert "config= must be a dataclass" in broken["dict_config_test"][1]
        assert "no_update_test" not in CONTROLLERS and "dict_config_test" not in CONTROLLERS
        with pytest.raises(ConfigError, match=r"controller plugin 'no_update_test' \(package \w+\) is broken"):
            make_controller("no_update_test")
    finally:
        CONTROLLERS.unregister("no_update_test")
        CONTROLLERS.unregister("dict_config_test")
    assert "no_update_test" not in CONTROLLERS.broken()


class Hold2(Controller):
    def reset(self, initial):
        pass

    def update(self, image, applied):
        return applied


def test_run_time_needs_are_named():
    """The oracle needs the simulator's scene; the learned controller a checkpoint: asking without says so."""
    with pytest.raises(ConfigError, match="needs scene, sensor, n_frames at run time"):
        make_controller("oracle", {})
    with pytest.raises(ConfigError, match="needs checkpoint"):
        make_controller("learned", {}, ControllerContext())


def test_agae_and_the_fixed_warm_up_meter_with_the_sensors_response():
    """The composed config hands the sensor's response keys to AG+AE and to the fixed controller's warm-up AG+AE."""
    from stages.compose import compose_config

    cfg = compose_config(["sensor.response_curve=gamma", "sensor.response_gamma_rgb=[2.6,2.1,2.3]",
                          "sensor.white_balance_rgb=[1.0,1.2,0.9]"])
    for block in (cfg["controllers"]["agae"], cfg["controllers"]["fixed"]["agae"]):
        assert block["response_curve"] == "gamma" and list(block["response_gamma_rgb"]) == [2.6, 2.1, 2.3]
        assert list(block["white_balance_rgb"]) == [1.0, 1.2, 0.9]
    make_controller("fixed", cfg["controllers"]["fixed"])  # builds (validates) with the per-channel keys
