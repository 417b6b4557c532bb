"""Mean-intensity rule: exact factors, exposure-first split, clamps, black/saturated frames."""

import math

import numpy as np
import pytest

from expoctl.controllers.base import Settings
from expoctl.controllers.mean_intensity import MeanIntensityController
from expoctl.errors import ConfigError


def _img(values, shape=(10, 10)):
    """Grey RGB image whose luma mean is the mean of `values` (split into equal horizontal bands)."""
    bands = np.array_split(np.zeros(shape, np.uint8), len(values))
    rows = [np.full(b.shape, v, np.uint8) for b, v in zip(bands, values)]
    return np.repeat(np.concatenate(rows)[..., None], 3, axis=2)


def test_too_dark_image_raises_exposure_by_the_exact_factor():
    c = MeanIntensityController()
    out = c.update(_img([63, 64]), Settings(0.0, 1000.0))  # mean 63.5
    assert out.gain_db == 0.0
    assert out.exposure_us == pytest.approx(1000.0 * (1 + 0.2 * (127.5 / 63.5 - 1)), rel=1e-12)


def test_at_target_nothing_changes_and_bright_frames_lower_exposure():
    c = MeanIntensityController()
    out = c.update(_img([127, 128]), Settings(3.0, 2000.0))  # same product, gain handed back to exposure
    assert out.gain_db == 0.0 and out.exposure_us == pytest.approx(2000.0 * 10 ** (3 / 20))
    out = c.update(_img([255]), Settings(0.0, 2000.0))
    assert out.exposure_us == pytest.approx(2000.0 * 0.9)  # saturated: 1 + 0.2·(0.5 − 1) = 0.9 at most


def test_exposure_first_then_gain():
    c = MeanIntensityController()
    out = c.update(_img([63, 64]), Settings(0.0, 28000.0))
    factor = 1 + 0.2 * (127.5 / 63.5 - 1)
    assert out.exposure_us == 30000.0
    assert out.gain_db == pytest.approx(20 * math.log10(28000.0 * factor / 30000.0))
    # with gain up, a bright frame first takes gain back down before exposure moves
    out = c.update(_img([255]), Settings(3.0, 30000.0))
    assert out.exposure_us == 30000.0 and out.gain_db == pytest.approx(3.0 + 20 * math.log10(0.9))


@pytest.mark.parametrize("code,expected", [(0, Settings(30.0, 30000.0)), (255, Settings(0.0, 75.0))])
def test_black_and_saturated_frames_converge_to_the_limits_without_nan(code, expected):
    c = MeanIntensityController()
    s = Settings(10.0, 3000.0)
    for _ in range(100):
        s = c.update(_img([code]), s)
        assert np.isfinite([s.gain_db, s.exposure_us]).all() and s == s.clamped()
    assert s.gain_db == pytest.approx(expected.gain_db) and s.exposure_us == pytest.approx(expected.exposure_us)


def test_black_frame_step_uses_the_mean_floor():
    out = MeanIntensityController().update(_img([0]), Settings(0.0, 100.0))
    assert out.exposure_us == pytest.approx(100.0 * (1 + 0.2 * 126.5))


@pytest.mark.parametrize(
    "params,key",
    [({"k": 0}, "controllers.mean_intensity.k"), ({"target_mean": 300}, "controllers.mean_intensity.target_mean"),
     ({"min_mean": 0}, "controllers.mean_intensity.min_mean"), ({"kp": 1}, "controllers.mean_intensity.kp")],
)
def test_bad_config(params, key):
    with pytest.raises(ConfigError) as e:
        MeanIntensityController(params)
    assert e.value.key == key
