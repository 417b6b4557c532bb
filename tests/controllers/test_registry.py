"""Registry: names build the right controllers from their config sections; the YAML defaults are valid."""

from pathlib import Path

import numpy as np
import pytest

from expoctl.controllers.base import Controller, Settings
from expoctl.controllers.registry import CONTROLLERS, make_controller, register
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


def test_register_extends_the_registry():
    class Hold(Controller):
        name = "hold_test"

        def reset(self, initial):
            self.s = initial

        def update(self, image, applied):
            return self.s

    register("hold_test", lambda params: Hold())
    try:
        assert make_controller("hold_test").name == "hold_test"
    finally:
        del CONTROLLERS["hold_test"]


def test_agae_and_the_fixed_warm_up_meter_with_the_sensors_response():
    """The composed config hands the sensor's response keys to AG+AE and to the fixed controller's warm-up AG+AE."""
    from stages.compose import compose_config

    cfg = compose_config(["sensor.response_curve=gamma", "sensor.response_gamma_rgb=[2.6,2.1,2.3]",
                          "sensor.white_balance_rgb=[1.0,1.2,0.9]"])
    for block in (cfg["controllers"]["agae"], cfg["controllers"]["fixed"]["agae"]):
        assert block["response_curve"] == "gamma" and list(block["response_gamma_rgb"]) == [2.6, 2.1, 2.3]
        assert list(block["white_balance_rgb"]) == [1.0, 1.2, 0.9]
    make_controller("fixed", cfg["controllers"]["fixed"])  # builds (validates) with the per-channel keys
