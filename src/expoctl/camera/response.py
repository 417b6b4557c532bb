"""Camera response: linear normalised signal [0, 1] ↔ delivered 8-bit value.

Machine-vision cameras deliver gamma-encoded 8-bit images (the paper's were BGR8/RGB JPEG). The default is the sRGB
transfer curve (linear toe below 0.0031308, then 1.055·x^(1/2.4) − 0.055), which is also what the AG+AE model
inverts to meter in the linear domain. A plain power law (`gamma`) is available for fitting real cameras.
"""

from __future__ import annotations

import numpy as np

CURVES = ("srgb", "gamma", "linear")


def _forward(x: np.ndarray, curve: str, gamma: float) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    if curve == "srgb":
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    if curve == "gamma":
        return np.power(x, 1.0 / gamma)
    return x


class Response:
    """A monotone response curve with an exact 8-bit inverse lookup table."""

    def __init__(self, curve: str = "srgb", gamma: float = 2.2):
        if curve not in CURVES:
            raise ValueError(f"unknown response curve {curve!r} (known: {CURVES})")
        if not gamma > 0:
            raise ValueError(f"gamma must be positive, got {gamma}")
        self.curve, self.gamma = curve, float(gamma)
        # inverse: the linear value at the centre of each code's bin (code / 255 through the inverse curve)
        codes = np.arange(256) / 255.0
        self._inverse_lut = self._invert(codes).astype(np.float32)

    def _invert(self, y: np.ndarray) -> np.ndarray:
        if self.curve == "srgb":
            return np.where(y <= 0.04045, y / 12.92, np.power((y + 0.055) / 1.055, 2.4))
        if self.curve == "gamma":
            return np.power(y, self.gamma)
        return y

    def linear_to_8bit(self, x_norm: np.ndarray) -> np.ndarray:
        """Linear signal (0 = black level, 1 = ADC full scale) → uint8 (rounded to the nearest code).

        The sensor calls this once per ADC code to build its own lookup table, so exactness beats speed here.
        """
        y = _forward(np.asarray(x_norm, dtype=np.float64), self.curve, self.gamma)
        return np.clip(np.round(y * 255.0), 0, 255).astype(np.uint8)

    def uint8_to_linear(self, image: np.ndarray) -> np.ndarray:
        """Delivered uint8 image → linear [0, 1] float32 (exact inverse of each code)."""
        return self._inverse_lut[np.asarray(image, dtype=np.uint8)]


_DEFAULT = Response()


def linear_to_8bit(x_norm: np.ndarray) -> np.ndarray:
    """sRGB-encode a linear [0, 1] signal to uint8 (the default camera response)."""
    return _DEFAULT.linear_to_8bit(x_norm)


def uint8_to_linear(image: np.ndarray) -> np.ndarray:
    """Invert the default (sRGB) response: uint8 → linear [0, 1] float32."""
    return _DEFAULT.uint8_to_linear(image)
