"""The 32-byte SAD used by the matcher: the SSE2 path equals the plain byte loop."""

import numpy as np
from numba import njit

from expoctl.features.viso.sad import _sad32_loop, sad32


@njit
def _all_pairs(a, b):
    out = np.empty((len(a), len(b), 2), np.int64)
    for i in range(len(a)):
        for j in range(len(b)):
            out[i, j, 0] = sad32(a, i, b, j)
            out[i, j, 1] = _sad32_loop(a, i, b, j)
    return out


def test_sad32_matches_numpy_on_random_and_extreme_bytes():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (20, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (15, 32), dtype=np.uint8)
    a[0] = 0
    b[0] = 255  # the maximum cost 32 · 255 = 8160
    out = _all_pairs(a, b)
    expected = np.abs(a[:, None, :].astype(np.int64) - b[None, :, :].astype(np.int64)).sum(axis=2)
    assert (out[:, :, 0] == expected).all() and (out[:, :, 1] == expected).all()
    assert out[0, 0, 0] == 8160
