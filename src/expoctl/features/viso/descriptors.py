"""Descriptors of the libviso2-style matcher (spec §5 and §6 refinement).

The 32-byte matching descriptor is read from the matching-resolution gradient images (du byte, then dv byte, per
offset). The 16-byte refinement descriptor is read from the full-resolution gradients.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# (dx, dy) offsets of the 32-byte descriptor, in byte order (each gives a du byte then a dv byte)
DESCRIPTOR_OFFSETS = np.array(
    [(-3, -1), (-3, 1), (-1, -1), (-1, 1), (3, -1), (3, 1), (1, -1), (1, 1),
     (-1, -5), (-1, 5), (1, -5), (1, 5), (-5, -3), (-5, 3), (5, -3), (5, 3)],
    np.int32,
)  # fmt: skip

# refinement descriptor: 12 du samples (the centre twice), then 4 dv samples
REFINE_DU_OFFSETS = np.array(
    [(0, -2), (-2, -1), (0, -1), (2, -1), (-1, 0), (0, 0), (0, 0), (1, 0), (-2, 1), (0, 1), (2, 1), (0, 2)], np.int32
)
REFINE_DV_OFFSETS = np.array([(0, -1), (-1, 0), (1, 0), (0, 1)], np.int32)


@njit(cache=True)
def _descriptors(du, dv, u, v, offsets):
    out = np.empty((len(u), 32), np.uint8)
    for i in range(len(u)):
        for k in range(16):
            x = u[i] + offsets[k, 0]
            y = v[i] + offsets[k, 1]
            out[i, 2 * k] = du[y, x]
            out[i, 2 * k + 1] = dv[y, x]
    return out


def descriptors(du: np.ndarray, dv: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 32) uint8 descriptors at integer positions (u, v) of the gradient images du, dv.

    Positions must lie at least 5 px inside the image (the detector's margin guarantees it)."""
    u = np.asarray(u, np.int64)
    v = np.asarray(v, np.int64)
    h, w = du.shape
    if len(u) and (u.min() < 5 or v.min() < 5 or u.max() >= w - 5 or v.max() >= h - 5):
        raise ValueError("descriptor positions must lie at least 5 px inside the image")
    return _descriptors(du, dv, u, v, DESCRIPTOR_OFFSETS)


def refinement_descriptor(du: np.ndarray, dv: np.ndarray, u: int, v: int) -> np.ndarray:
    """16-byte refinement descriptor at (u, v) of the full-resolution gradients (for tests; the matcher inlines it)."""
    a = du[v + REFINE_DU_OFFSETS[:, 1], u + REFINE_DU_OFFSETS[:, 0]]
    b = dv[v + REFINE_DV_OFFSETS[:, 1], u + REFINE_DV_OFFSETS[:, 0]]
    return np.concatenate([a, b]).astype(np.uint8)
