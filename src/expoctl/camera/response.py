"""Camera response: linear normalised signal [0, 1] ↔ delivered 8-bit value.

Machine-vision cameras deliver gamma-encoded 8-bit images (the paper's were BGR8/RGB JPEG). The default is the sRGB
transfer curve (linear toe below 0.0031308, then 1.055·x^(1/2.4) − 0.055), which is also what the AG+AE model
inverts to meter in the linear domain. A plain power law (`gamma`) is available for fitting real cameras.

Per channel c (R, G, B) the curve may differ, as it does in real pipelines (white balance, per-channel tone curves,
film): code_c / 255 = pedestal_c + (1 − pedestal_c)·F_c(min(white_balance_c·x_c, 1)), with F_c the named curve (for
`gamma`, its own exponent gamma_c). The pedestal is an output offset in units of the 8-bit range (a real scan or JPEG
pipeline sits on a flare / black pedestal; a negative one clips the darkest codes to 0), the white-balance factor a
digital gain on the linear signal before the curve. `expoctl.camera.calibration.fit_parametric_response(...,
per_channel=True)` fits exactly this model to a real bracketed stack. With all channels equal (the default) every
function below gives the same value for each channel, so any array shape is accepted.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from expoctl.errors import ConfigError

CURVES = ("srgb", "gamma", "linear")
SATURATED_DN = 250  # a delivered 8-bit code (or grey level) at or above this counts as (near) saturated, clipped
DARK_DN = 5  # … and at or below this as black: within a few codes of the dark floor, no texture survives the noise


def apply_curve(x: np.ndarray, curve: str, gamma) -> np.ndarray:
    """The transfer curve F (`curve`: srgb | gamma | linear) of a linear signal, clipped to [0, 1] first."""
    x = np.clip(x, 0.0, 1.0)
    if curve == "srgb":
        return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    if curve == "gamma":
        return np.power(x, 1.0 / gamma)
    return x


def _inverse(y: np.ndarray, curve: str, gamma) -> np.ndarray:
    y = np.clip(y, 0.0, 1.0)
    if curve == "srgb":
        return np.where(y <= 0.04045, y / 12.92, np.power((y + 0.055) / 1.055, 2.4))
    if curve == "gamma":
        return np.power(y, gamma)
    return y


def _triple(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.ndim == 0:
        a = np.repeat(a, 3)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be a finite number or three (R, G, B), got {v!r}")
    return a


class Response:
    """A monotone response curve (optionally per RGB channel) with an exact 8-bit inverse lookup table.

    gamma: one exponent, or three (R, G, B), for curve 'gamma'; pedestal: output offset in units of the 8-bit range,
    one or three, each in (−1, 1); white_balance: three digital gains on the linear signal, each > 0."""

    def __init__(self, curve: str = "srgb", gamma: float | Sequence[float] = 2.2,
                 pedestal: float | Sequence[float] = 0.0, white_balance: Sequence[float] = (1.0, 1.0, 1.0)):
        if curve not in CURVES:
            raise ValueError(f"unknown response curve {curve!r} (known: {CURVES})")
        self.curve = curve
        self.gamma_rgb = _triple(gamma, "gamma")
        self.pedestal_rgb = _triple(pedestal, "pedestal")
        self.white_balance_rgb = _triple(white_balance, "white_balance")
        if not np.all(self.gamma_rgb > 0):
            raise ValueError(f"gamma must be positive, got {gamma}")
        if not np.all(np.abs(self.pedestal_rgb) < 1):
            raise ValueError(f"pedestal must lie in (-1, 1), got {pedestal}")
        if not np.all(self.white_balance_rgb > 0):
            raise ValueError(f"white_balance must be positive, got {white_balance}")
        # the curve ignores gamma unless it is 'gamma': only parameters that change the curve make it per channel
        used = [self.pedestal_rgb, self.white_balance_rgb] + ([self.gamma_rgb] if curve == "gamma" else [])
        self.per_channel = any(np.ptp(p) > 0 for p in used)
        # inverse: the linear value at the centre of each code's bin (code / 255 through the inverse curve), (256, 3)
        codes = np.arange(256) / 255.0
        self._inverse_lut = np.stack([self._invert(codes, c) for c in range(3)], axis=1).astype(np.float32)

    def _invert(self, y: np.ndarray, c: int) -> np.ndarray:
        p = self.pedestal_rgb[c]
        return _inverse((y - p) / (1.0 - p), self.curve, self.gamma_rgb[c]) / self.white_balance_rgb[c]

    def _encode(self, x: np.ndarray, c: int) -> np.ndarray:
        p = self.pedestal_rgb[c]
        return p + (1.0 - p) * apply_curve(self.white_balance_rgb[c] * x, self.curve, self.gamma_rgb[c])

    def _require_rgb(self, a: np.ndarray, what: str) -> None:
        if self.per_channel and (a.ndim == 0 or a.shape[-1] != 3):
            raise ValueError(f"a per-channel response needs {what} with a last axis of 3 (R, G, B), got {a.shape}")

    def linear_to_8bit(self, x_norm: np.ndarray) -> np.ndarray:
        """Linear signal (0 = black level, 1 = ADC full scale) → uint8 (rounded to the nearest code).

        x_norm (..., 3) is encoded per channel; a channel-uniform response accepts any shape. The sensor calls this
        once per ADC code to build its own lookup table, so exactness beats speed here.
        """
        x = np.asarray(x_norm, dtype=np.float64)
        self._require_rgb(x, "a linear signal")
        if self.per_channel:
            y = np.stack([self._encode(x[..., c], c) for c in range(3)], axis=-1)
        else:
            y = self._encode(x, 0)
        return np.clip(np.round(y * 255.0), 0, 255).astype(np.uint8)

    def uint8_to_linear(self, image: np.ndarray) -> np.ndarray:
        """Delivered uint8 image → linear [0, 1] float32 (exact inverse of each code, per channel)."""
        a = np.asarray(image, dtype=np.uint8)
        self._require_rgb(a, "an image")
        if self.per_channel:
            return self._inverse_lut[a, np.arange(3)]
        return self._inverse_lut[a, 0]


def response_from_config(d: dict, key: str) -> Response:
    """The `Response` a config block describes (the sensor's and AG+AE's keys): response_curve, response_gamma and
    the optional per-channel response_gamma_rgb (null = response_gamma for all), response_pedestal_rgb and
    white_balance_rgb. Raises ConfigError naming the offending key."""
    curve = d.get("response_curve", "srgb")
    if curve not in CURVES:
        raise ConfigError(f"{key}.response_curve", f"must be one of {list(CURVES)}, got {curve!r}")
    gamma = d.get("response_gamma", 2.2)
    if isinstance(gamma, bool) or not isinstance(gamma, (int, float)) or not math.isfinite(gamma) or gamma <= 0:
        raise ConfigError(f"{key}.response_gamma", f"must be a positive number, got {gamma!r}")
    gamma_rgb = d.get("response_gamma_rgb")
    checks = (("response_gamma_rgb", gamma_rgb, lambda v: v > 0, "positive"),
              ("response_pedestal_rgb", d.get("response_pedestal_rgb", (0.0, 0.0, 0.0)), lambda v: -1 < v < 1,
               "in (-1, 1) (units of the 8-bit range)"),
              ("white_balance_rgb", d.get("white_balance_rgb", (1.0, 1.0, 1.0)), lambda v: v > 0, "positive"))
    values = {}
    for name, v, ok, what in checks:
        if v is None and name == "response_gamma_rgb":
            continue
        good = isinstance(v, (list, tuple)) and len(v) == 3 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and ok(x) for x in v)
        if not good:
            null = "null or " if name == "response_gamma_rgb" else ""
            raise ConfigError(f"{key}.{name}", f"must be {null}three numbers [R, G, B], each {what}; got {v!r}")
        values[name] = tuple(float(x) for x in v)
    return Response(curve, values.get("response_gamma_rgb", float(gamma)), values["response_pedestal_rgb"],
                    values["white_balance_rgb"])


_DEFAULT = Response()


def linear_to_8bit(x_norm: np.ndarray) -> np.ndarray:
    """sRGB-encode a linear [0, 1] signal to uint8 (the default camera response)."""
    return _DEFAULT.linear_to_8bit(x_norm)


def uint8_to_linear(image: np.ndarray) -> np.ndarray:
    """Invert the default (sRGB) response: uint8 → linear [0, 1] float32."""
    return _DEFAULT.uint8_to_linear(image)
