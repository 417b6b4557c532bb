"""Scene inputs the sensor refuses: NaN luminance (it would index the DN→8-bit table out of range)."""

from __future__ import annotations

import numpy as np
import pytest

from expoctl.camera.sensor import Sensor, SensorConfig
from expoctl.errors import InputError


def test_nan_luminance_is_rejected():
    sensor = Sensor(SensorConfig(), 4, 4)
    lum = np.ones((4, 4, 3), np.float32)
    lum[1, 2, 0] = np.nan
    for call in (sensor.capture, sensor.capture_raw):
        with pytest.raises(InputError, match="NaN"):
            call(lum, 1000.0, 0.0, np.random.default_rng(0))
