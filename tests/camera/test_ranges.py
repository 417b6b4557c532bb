"""Setting ranges and the two exposure scalings (linear = paper, log = EV over the range)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from expoctl.camera.ranges import (EXPOSURE_US_MAX, EXPOSURE_US_MIN, exposure_to_norm, norm_to_exposure,
                                   rescale_exposure_norm)

STOPS = math.log2(EXPOSURE_US_MAX / EXPOSURE_US_MIN)  # 8.64 stops between 75 and 30000 µs


@pytest.mark.parametrize("scale", ["linear", "log"])
def test_range_ends_map_to_0_and_1_and_round_trip(scale):
    assert exposure_to_norm([EXPOSURE_US_MIN, EXPOSURE_US_MAX], scale) == pytest.approx([0.0, 1.0], abs=1e-15)
    e = np.geomspace(EXPOSURE_US_MIN, EXPOSURE_US_MAX, 17)
    assert norm_to_exposure(exposure_to_norm(e, scale), scale) == pytest.approx(e, rel=1e-12)


def test_log_scaling_is_uniform_in_ev():
    # every doubling of exposure is the same step, 1 / 8.64, wherever it is in the range
    n = exposure_to_norm([100.0, 200.0, 10000.0, 20000.0], "log")
    assert n[1] - n[0] == pytest.approx(1 / STOPS) and n[3] - n[2] == pytest.approx(1 / STOPS)
    # ... whereas linear puts all of 75 µs–1 ms into the bottom 3.1 % of [0, 1]
    assert exposure_to_norm(1000.0, "linear") == pytest.approx(925 / 29925)
    assert exposure_to_norm(1000.0, "log") == pytest.approx(math.log2(1000 / 75) / STOPS)


def test_unscaling_clamps_and_rescale_converts():
    assert norm_to_exposure([-0.5, 1.5], "log") == pytest.approx([EXPOSURE_US_MIN, EXPOSURE_US_MAX])
    lin = exposure_to_norm(2400.0, "linear")
    assert rescale_exposure_norm(lin, "linear", "log") == pytest.approx(math.log2(32) / STOPS)
    assert rescale_exposure_norm(0.25, "log", "log") == 0.25
    with pytest.raises(ValueError, match="exposure scale"):
        exposure_to_norm(100.0, "ln")
