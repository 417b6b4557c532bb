"""Image metrics shared by the baseline controllers (controllers.md §1–§4).

Every function takes an 8-bit image (H×W×3 RGB or H×W grey) or a float array and returns finite numbers for any
input, including all-black and all-saturated frames: controllers must never emit NaN.

Conventions
- "grey" is the plain mean of the R, G, B channels as float64 on the 0–255 scale (Shin's MATLAB averages the channels;
  see controllers.md §2).
- "linear" values are on [0, 1] of full scale, i.e. after inverting the camera response.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

ResponseInverse = Callable[[np.ndarray], np.ndarray]


# ----------------------------------------------------------------------------------------------- response / metering
def _srgb_decode(v: np.ndarray) -> np.ndarray:
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


_SRGB_LUT = _srgb_decode(np.arange(256, dtype=np.float64) / 255.0)


def srgb_uint8_to_linear(img: np.ndarray) -> np.ndarray:
    """Invert the sRGB transfer curve: uint8 code → linear [0, 1]. Default response for AG+AE until a calibrated
    camera response is supplied (the simulator's is `expoctl.camera.response.uint8_to_linear`)."""
    return _SRGB_LUT[np.asarray(img, dtype=np.uint8)]


def srgb_linear_to_uint8(linear: np.ndarray) -> np.ndarray:
    """Forward sRGB curve (linear [0, 1] → uint8), the inverse of `srgb_uint8_to_linear` up to quantisation."""
    v = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    enc = np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)
    return np.clip(np.rint(enc * 255.0), 0, 255).astype(np.uint8)


#: fraction of the frame area metered by the FLIR modes (Spinnaker docs: spot ≈ 3 %, partial ≈ 11 %, centred)
METERING_AREA_FRACTION = {"average": 1.0, "spot": 0.03, "partial": 0.11}


def metering_window(shape: tuple[int, ...], mode: str = "average", roi=None) -> tuple[slice, slice]:
    """Row/column slices of the metered region. `roi` = (x0, y0, x1, y1) as fractions of width/height overrides
    `mode` (the camera's AasRoi). Spot/partial are centred squares-in-proportion covering the mode's area fraction."""
    h, w = int(shape[0]), int(shape[1])
    if roi is not None:
        x0, y0, x1, y1 = (float(v) for v in roi)
        r0, r1 = int(np.floor(y0 * h)), int(np.ceil(y1 * h))
        c0, c1 = int(np.floor(x0 * w)), int(np.ceil(x1 * w))
    else:
        side = np.sqrt(METERING_AREA_FRACTION[mode])  # same fraction of each dimension keeps the frame's aspect
        rh, rw = max(1, int(round(h * side))), max(1, int(round(w * side)))
        r0, c0 = (h - rh) // 2, (w - rw) // 2
        r1, c1 = r0 + rh, c0 + rw
    r0, c0 = max(0, min(r0, h - 1)), max(0, min(c0, w - 1))
    return slice(r0, max(r0 + 1, min(r1, h))), slice(c0, max(c0 + 1, min(c1, w)))


def metered_linear_mean(img: np.ndarray, response_inverse: ResponseInverse, mode: str = "average", roi=None) -> float:
    """Mean of the linear image (channels averaged) over the metering region, in [0, 1] of full scale."""
    rows, cols = metering_window(img.shape, mode, roi)
    lin = np.asarray(response_inverse(np.asarray(img)[rows, cols]), dtype=np.float64)
    m = float(np.mean(lin))
    return m if np.isfinite(m) else 0.0


def grey(img: np.ndarray) -> np.ndarray:
    """Channel mean on the 0–255 scale as float64 (H×W)."""
    a = np.asarray(img, dtype=np.float64)
    return a.mean(axis=2) if a.ndim == 3 else a
