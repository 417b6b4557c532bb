"""Gain and exposure ranges and the network's linear [0, 1] scaling (DESIGN: decisions that hold everywhere)."""

from __future__ import annotations

import numpy as np

GAIN_DB_MIN = 0.0
GAIN_DB_MAX = 30.0
EXPOSURE_US_MIN = 75.0
EXPOSURE_US_MAX = 30000.0


def gain_to_norm(gain_db):
    """Gain in dB → [0, 1] (paper: g / 30)."""
    return (np.asarray(gain_db, dtype=np.float64) - GAIN_DB_MIN) / (GAIN_DB_MAX - GAIN_DB_MIN)


def exposure_to_norm(exposure_us):
    """Exposure in µs → [0, 1] (paper: (e − 75) / (30000 − 75))."""
    return (np.asarray(exposure_us, dtype=np.float64) - EXPOSURE_US_MIN) / (EXPOSURE_US_MAX - EXPOSURE_US_MIN)


def norm_to_gain(gain_norm):
    """[0, 1] → gain in dB; inputs are clamped to [0, 1] first (network outputs are unbounded)."""
    g = np.clip(np.asarray(gain_norm, dtype=np.float64), 0.0, 1.0)
    return GAIN_DB_MIN + g * (GAIN_DB_MAX - GAIN_DB_MIN)


def norm_to_exposure(exposure_norm):
    """[0, 1] → exposure in µs; inputs are clamped to [0, 1] first."""
    e = np.clip(np.asarray(exposure_norm, dtype=np.float64), 0.0, 1.0)
    return EXPOSURE_US_MIN + e * (EXPOSURE_US_MAX - EXPOSURE_US_MIN)


def clamp_settings(gain_db: float, exposure_us: float) -> tuple[float, float]:
    """Clamp a (gain dB, exposure µs) pair into the camera's valid range."""
    return (
        float(np.clip(gain_db, GAIN_DB_MIN, GAIN_DB_MAX)),
        float(np.clip(exposure_us, EXPOSURE_US_MIN, EXPOSURE_US_MAX)),
    )


def exposure_value_ev(gain_db, exposure_us):
    """log2 of the total exposure product t·10^(g/20) (t in seconds): +1 EV = twice the signal."""
    return np.log2(np.asarray(exposure_us, dtype=np.float64) * 1e-6) + np.asarray(gain_db, dtype=np.float64) / (
        20.0 * np.log10(2.0)
    )
