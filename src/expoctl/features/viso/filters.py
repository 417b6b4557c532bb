"""Filter responses of the libviso2-style detector (spec §2–§3).

All filters are correlations (kernel[dy+2][dx+2] multiplies I(x+dx, y+dy)) with exact int32 sums, computed
separably in numba: a row pass into a 5-row ring buffer, then the column pass, so the temporaries stay in cache.
The 2-pixel border, which nothing within the detector's margin reads, holds "no response" (0, or 128 for gradients).
"""

from __future__ import annotations

import numpy as np
from numba import njit

# Blob: -1 on the outer ring, +1 on the inner ring, +8 at the centre (= -box5 + 2·box3 + 7·centre)
BLOB_KERNEL = -np.ones((5, 5), np.int32)
BLOB_KERNEL[1:4, 1:4] = 1
BLOB_KERNEL[2, 2] = 8
# Corner / checkerboard: outer(a, a) with a = (1, 1, 0, -1, -1)
CORNER_KERNEL = np.outer([1, 1, 0, -1, -1], [1, 1, 0, -1, -1]).astype(np.int32)


def half_resolution(grey: np.ndarray) -> np.ndarray:
    """floor(W/2)×floor(H/2) image whose pixels are the truncated mean of 2×2 blocks; an odd last row/column is dropped."""
    h, w = grey.shape[0] // 2, grey.shape[1] // 2
    g = grey[: 2 * h, : 2 * w].astype(np.uint16)
    return ((g[0::2, 0::2] + g[0::2, 1::2] + g[1::2, 0::2] + g[1::2, 1::2]) >> 2).astype(np.uint8)


@njit(cache=True)
def _sobel_row_pass(img, y, r, sm, de):
    # s = (1, 4, 6, 4, 1) smooths, d = (1, 2, 0, -2, -1) differentiates (left / top brighter → +)
    for x in range(2, img.shape[1] - 2):
        a0 = np.int32(img[y, x - 2])
        a1 = np.int32(img[y, x - 1])
        a2 = np.int32(img[y, x])
        a3 = np.int32(img[y, x + 1])
        a4 = np.int32(img[y, x + 2])
        sm[r, x] = a0 + 4 * (a1 + a3) + 6 * a2 + a4
        de[r, x] = a0 - a4 + 2 * (a1 - a3)


@njit(cache=True)
def _sobel_sums(img):
    h, w = img.shape
    s_u = np.zeros((h, w), np.int32)
    s_v = np.zeros((h, w), np.int32)
    sm = np.zeros((5, w), np.int32)  # ring buffers of the row pass
    de = np.zeros((5, w), np.int32)
    for y in range(h):
        _sobel_row_pass(img, y, y % 5, sm, de)
        if y >= 4:
            r0, r1, r2, r3, r4 = (y - 4) % 5, (y - 3) % 5, (y - 2) % 5, (y - 1) % 5, y % 5
            for x in range(2, w - 2):
                s_u[y - 2, x] = de[r0, x] + de[r4, x] + 4 * (de[r1, x] + de[r3, x]) + 6 * de[r2, x]
                s_v[y - 2, x] = sm[r0, x] - sm[r4, x] + 2 * (sm[r1, x] - sm[r3, x])
    return s_u, s_v


@njit(cache=True)
def _sobel_bytes(img):
    h, w = img.shape
    du = np.full((h, w), 128, np.uint8)
    dv = np.full((h, w), 128, np.uint8)
    sm = np.zeros((5, w), np.int32)
    de = np.zeros((5, w), np.int32)
    for y in range(h):
        _sobel_row_pass(img, y, y % 5, sm, de)
        if y >= 4:
            r0, r1, r2, r3, r4 = (y - 4) % 5, (y - 3) % 5, (y - 2) % 5, (y - 1) % 5, y % 5
            for x in range(2, w - 2):
                su = de[r0, x] + de[r4, x] + 4 * (de[r1, x] + de[r3, x]) + 6 * de[r2, x]
                sv = sm[r0, x] - sm[r4, x] + 2 * (sm[r1, x] - sm[r3, x])
                # clip(floor(S / 128) + 128, 0, 255): >> on int32 is an arithmetic shift, i.e. floor division
                du[y - 2, x] = min(max((su >> 7) + 128, 0), 255)
                dv[y - 2, x] = min(max((sv >> 7) + 128, 0), 255)
    return du, dv


def sobel_raw(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact 5×5 Sobel sums (S_u, S_v) as int32: S_u smooths along v and differentiates along u (left brighter → +)."""
    return _sobel_sums(np.ascontiguousarray(grey, np.uint8))


def gradient_bytes(s: np.ndarray) -> np.ndarray:
    """libviso2's uint8 gradient encoding: clip(floor(S/128) + 128, 0, 255); `>>` is floor division for negatives."""
    return np.clip((s >> 7) + 128, 0, 255).astype(np.uint8)


def sobel_du_dv(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient images du, dv (uint8, H×W) of an 8-bit grey image: gradient_bytes of the Sobel sums, in one pass."""
    return _sobel_bytes(np.ascontiguousarray(grey, np.uint8))


@njit(cache=True)
def _blob_corner(img):
    h, w = img.shape
    f1 = np.zeros((h, w), np.int16)
    f2 = np.zeros((h, w), np.int16)
    box5 = np.zeros((5, w), np.int32)  # ring buffers of the row pass
    box3 = np.zeros((5, w), np.int32)
    chk = np.zeros((5, w), np.int32)  # Σ a[dx]·I along u
    for y in range(h):
        r = y % 5
        for x in range(2, w - 2):
            a0 = np.int32(img[y, x - 2])
            a1 = np.int32(img[y, x - 1])
            a2 = np.int32(img[y, x])
            a3 = np.int32(img[y, x + 1])
            a4 = np.int32(img[y, x + 2])
            b3 = a1 + a2 + a3
            box3[r, x] = b3
            box5[r, x] = b3 + a0 + a4
            chk[r, x] = a0 + a1 - a3 - a4
        if y < 4:
            continue
        yc = y - 2
        r0, r1, r2, r3, r4 = (y - 4) % 5, (y - 3) % 5, (y - 2) % 5, (y - 1) % 5, r
        for x in range(2, w - 2):
            b5 = box5[r0, x] + box5[r1, x] + box5[r2, x] + box5[r3, x] + box5[r4, x]
            b3 = box3[r1, x] + box3[r2, x] + box3[r3, x]
            f1[yc, x] = -b5 + 2 * b3 + 7 * np.int32(img[yc, x])
            f2[yc, x] = chk[r0, x] + chk[r1, x] - chk[r3, x] - chk[r4, x]
    return f1, f2


def blob_corner(grey: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Blob (f1) and corner/checkerboard (f2) responses as int16, H×W."""
    return _blob_corner(np.ascontiguousarray(grey, np.uint8))
