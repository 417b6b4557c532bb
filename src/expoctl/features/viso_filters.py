"""Filter responses of the libviso2-style detector (spec §2–§3).

All filters are correlations (kernel[dy+2][dx+2] multiplies I(x+dx, y+dy)) with exact integer sums. The Sobel sums
run in numba with int32; blob and corner run through OpenCV in float32, which is exact here because every partial sum
is an integer far below 2**24. Border pixels are meaningless, but nothing within the detector's margin reads them.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

_CHECKER = np.array([1, 1, 0, -1, -1], np.float32)  # a: corner kernel is outer(a, a)
# Blob: -1 on the outer ring, +1 on the inner ring, +8 at the centre
BLOB_KERNEL = -np.ones((5, 5), np.float32)
BLOB_KERNEL[1:4, 1:4] = 1
BLOB_KERNEL[2, 2] = 8


def half_resolution(grey: np.ndarray) -> np.ndarray:
    """floor(W/2)×floor(H/2) image whose pixels are the truncated mean of 2×2 blocks; an odd last row/column is dropped."""
    h, w = grey.shape[0] // 2, grey.shape[1] // 2
    g = grey[: 2 * h, : 2 * w].astype(np.uint16)
    return ((g[0::2, 0::2] + g[0::2, 1::2] + g[1::2, 0::2] + g[1::2, 1::2]) >> 2).astype(np.uint8)


def _correlate_sep(img_f32: np.ndarray, kx: np.ndarray, ky: np.ndarray) -> np.ndarray:
    return cv2.sepFilter2D(img_f32, cv2.CV_32F, kx, ky, borderType=cv2.BORDER_REFLECT_101)


@njit(cache=True)
def _sobel_sums(img):
    # separable: s = (1, 4, 6, 4, 1) smooths, d = (1, 2, 0, -2, -1) differentiates (left / top brighter → +)
    h, w = img.shape
    s_u = np.zeros((h, w), np.int32)
    s_v = np.zeros((h, w), np.int32)
    sm = np.zeros((h, w), np.int32)  # Σ s[dx]·I along u
    de = np.zeros((h, w), np.int32)  # Σ d[dx]·I along u
    for y in range(h):
        for x in range(2, w - 2):
            a0 = np.int32(img[y, x - 2])
            a1 = np.int32(img[y, x - 1])
            a2 = np.int32(img[y, x])
            a3 = np.int32(img[y, x + 1])
            a4 = np.int32(img[y, x + 2])
            sm[y, x] = a0 + 4 * a1 + 6 * a2 + 4 * a3 + a4
            de[y, x] = a0 + 2 * a1 - 2 * a3 - a4
    for y in range(2, h - 2):
        for x in range(2, w - 2):
            s_u[y, x] = de[y - 2, x] + 4 * de[y - 1, x] + 6 * de[y, x] + 4 * de[y + 1, x] + de[y + 2, x]
            s_v[y, x] = sm[y - 2, x] + 2 * sm[y - 1, x] - 2 * sm[y + 1, x] - sm[y + 2, x]
    return s_u, s_v


def sobel_raw(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact 5×5 Sobel sums (S_u, S_v) as int32: S_u smooths along v and differentiates along u (left brighter → +).

    The 2-pixel border, which the detector never reads, is 0 (it encodes as 128, "no gradient").
    """
    return _sobel_sums(np.ascontiguousarray(grey, np.uint8))


def gradient_bytes(s: np.ndarray) -> np.ndarray:
    """libviso2's uint8 gradient encoding: clip(floor(S/128) + 128, 0, 255); `>>` is floor division for negatives."""
    return np.clip((s >> 7) + 128, 0, 255).astype(np.uint8)


def sobel_du_dv(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient images du, dv (uint8, H×W) of an 8-bit grey image."""
    s_u, s_v = sobel_raw(grey)
    return gradient_bytes(s_u), gradient_bytes(s_v)


def blob_corner(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Blob (f1) and corner/checkerboard (f2) responses as int16, H×W."""
    f = grey.astype(np.float32)
    f1 = cv2.filter2D(f, cv2.CV_32F, BLOB_KERNEL, borderType=cv2.BORDER_REFLECT_101)
    f2 = _correlate_sep(f, _CHECKER, _CHECKER)
    return f1.astype(np.int16), f2.astype(np.int16)
