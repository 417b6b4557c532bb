"""Gain and exposure ranges and the network's [0, 1] scaling (docs/pipeline.md, Conventions that hold everywhere).

Two exposure scalings (`EXPOSURE_SCALES`):
- "linear" — the paper's (e − 75) / (30000 − 75). Labels and samples always store this one (the data contract).
- "log" — (log2 e − log2 75) / (log2 30000 − log2 75), i.e. EV above the shortest exposure over the 8.64-stop range.
  A camera's exposure is a photographic, ratio quantity (gain in dB already is one). Under the linear scaling every
  exposure below ~1 ms maps into [0, 0.03], so in daylight the exposure planes the network sees are all but constant
  and an L1 loss on linear values is dominated by the few long tunnel exposures. Measured on the default-scale data
  (docs/network.md, issue 6): a network on the linear scaling barely beat the constant predictor. A model records which
  scaling it was trained with (`model.exposure_scale`), and training and deployment convert through these functions.
"""

from __future__ import annotations

import numpy as np

GAIN_DB_MIN = 0.0
GAIN_DB_MAX = 30.0
EXPOSURE_US_MIN = 75.0  # the network's (the paper's) range; labels are scaled over it
EXPOSURE_US_MAX = 30000.0
# The camera's own shortest exposure, which its built-in AG+AE may use: FLIR documents 19 µs for the Blackfly S
# BFS-U3-32S4 (IMX252, the same 3.45 µm Pregius pixel and readout family as the rig's IMX265 BFS-U3-31S4, whose own
# page was not available to us). The simulated sensor, raw recordings and camera settings accept it; the network's
# outputs stay within [EXPOSURE_US_MIN, EXPOSURE_US_MAX].
SENSOR_EXPOSURE_US_MIN = 19.0


def gain_to_norm(gain_db):
    """Gain in dB → [0, 1] (paper: g / 30)."""
    return (np.asarray(gain_db, dtype=np.float64) - GAIN_DB_MIN) / (GAIN_DB_MAX - GAIN_DB_MIN)


EXPOSURE_SCALES = ("linear", "log")
_LOG2_MIN, _LOG2_MAX = np.log2(EXPOSURE_US_MIN), np.log2(EXPOSURE_US_MAX)


def _check_scale(scale: str) -> None:
    if scale not in EXPOSURE_SCALES:
        raise ValueError(f"exposure scale must be one of {EXPOSURE_SCALES}, got {scale!r}")


def exposure_to_norm(exposure_us, scale: str = "linear"):
    """Exposure in µs → [0, 1]: "linear" (paper: (e − 75) / (30000 − 75)) or "log" (EV over the range, module doc).

    The log scaling needs e > 0; values below 75 µs map below 0 and above 30000 µs above 1, as with linear."""
    _check_scale(scale)
    e = np.asarray(exposure_us, dtype=np.float64)
    if scale == "log":
        return (np.log2(e) - _LOG2_MIN) / (_LOG2_MAX - _LOG2_MIN)
    return (e - EXPOSURE_US_MIN) / (EXPOSURE_US_MAX - EXPOSURE_US_MIN)


def norm_to_gain(gain_norm):
    """[0, 1] → gain in dB; inputs are clamped to [0, 1] first (network outputs are unbounded)."""
    g = np.clip(np.asarray(gain_norm, dtype=np.float64), 0.0, 1.0)
    return GAIN_DB_MIN + g * (GAIN_DB_MAX - GAIN_DB_MIN)


def norm_to_exposure(exposure_norm, scale: str = "linear", clamp: bool = True):
    """[0, 1] → exposure in µs (inverse of `exposure_to_norm` with the same scale); inputs are clamped to [0, 1] first
    (network outputs are unbounded) unless `clamp` is false (a settings plane of a sensor exposure below 75 µs)."""
    _check_scale(scale)
    e = np.asarray(exposure_norm, dtype=np.float64)
    if clamp:
        e = np.clip(e, 0.0, 1.0)
    if scale == "log":
        return np.exp2(_LOG2_MIN + e * (_LOG2_MAX - _LOG2_MIN))
    return EXPOSURE_US_MIN + e * (EXPOSURE_US_MAX - EXPOSURE_US_MIN)


def rescale_exposure_norm(exposure_norm, from_scale: str, to_scale: str):
    """A normalised exposure in one scaling → the other (identity when equal; no clamping beyond [0, 1])."""
    if from_scale == to_scale:
        _check_scale(from_scale)
        return np.asarray(exposure_norm, dtype=np.float64)
    return exposure_to_norm(norm_to_exposure(exposure_norm, from_scale), to_scale)


def clamp_settings(gain_db: float, exposure_us: float) -> tuple[float, float]:
    """Clamp a (gain dB, exposure µs) pair into the camera's valid range (exposure down to the sensor's floor)."""
    return (
        float(np.clip(gain_db, GAIN_DB_MIN, GAIN_DB_MAX)),
        float(np.clip(exposure_us, SENSOR_EXPOSURE_US_MIN, EXPOSURE_US_MAX)),
    )


def exposure_value_ev(gain_db, exposure_us):
    """log2 of the total exposure product t·10^(g/20) (t in seconds): +1 EV = twice the signal."""
    return np.log2(np.asarray(exposure_us, dtype=np.float64) * 1e-6) + np.asarray(gain_db, dtype=np.float64) / (
        20.0 * np.log10(2.0)
    )
