"""The camera model: the gain / exposure ranges and their [0, 1] scaling (`ranges`), the response between linear
signal and delivered 8-bit codes (`response`) and the EMVA-1288 sensor (`sensor`). `calibration` (fitting response
and noise to real bracketed images, for the benchmarks) is imported on its own: it needs scipy.optimize.
"""

from expoctl.camera.ranges import (EXPOSURE_SCALES, EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN,
                                   SENSOR_EXPOSURE_US_MIN, clamp_settings, exposure_to_norm, exposure_value_ev,
                                   gain_to_norm, norm_to_exposure, norm_to_gain, rescale_exposure_norm)
from expoctl.camera.response import SATURATED_DN, response_from_config, uint8_to_linear
from expoctl.camera.sensor import Sensor, SensorConfig

__all__ = ["EXPOSURE_SCALES", "EXPOSURE_US_MAX", "EXPOSURE_US_MIN", "GAIN_DB_MAX", "GAIN_DB_MIN", "SATURATED_DN",
           "SENSOR_EXPOSURE_US_MIN", "Sensor", "SensorConfig", "clamp_settings", "exposure_to_norm",
           "exposure_value_ev", "gain_to_norm", "norm_to_exposure", "norm_to_gain", "rescale_exposure_norm",
           "response_from_config", "uint8_to_linear"]
