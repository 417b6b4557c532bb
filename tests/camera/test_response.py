from __future__ import annotations

import numpy as np
import pytest

from expoctl.camera.response import Response, linear_to_8bit, uint8_to_linear


@pytest.mark.parametrize("curve", ["srgb", "gamma", "linear"])
def test_round_trip_every_code(curve):
    r = Response(curve)
    codes = np.arange(256, dtype=np.uint8)
    np.testing.assert_array_equal(r.linear_to_8bit(r.uint8_to_linear(codes)), codes)


def test_srgb_known_values():
    assert linear_to_8bit(np.array([0.0, 1.0, 0.18])).tolist() == [0, 255, 118]  # 18 % grey → sRGB 118
    assert uint8_to_linear(np.array([255], np.uint8))[0] == pytest.approx(1.0)
    assert uint8_to_linear(np.array([118], np.uint8))[0] == pytest.approx(0.18, abs=0.002)


def test_monotone_and_clipped():
    out = linear_to_8bit(np.linspace(-0.5, 1.5, 1001))
    assert np.all(np.diff(out.astype(int)) >= 0) and out[0] == 0 and out[-1] == 255
