"""Block NMS on a constructed response map (spec §4): classes, ties, thresholds, window clipping, emission order."""

import numpy as np

from expoctl.features.viso.nms import block_nms


def test_block_nms_on_constructed_responses():
    # 41×41, n = 3, margin 9: block origins 12, 16, 20, 24, 28 (u0 < 41 − 3 − 9); window upper limit 41 − 1 − 9 = 31
    f1 = np.zeros((41, 41), np.int16)
    f2 = np.zeros((41, 41), np.int16)

    def put(f, u, v, x):
        f[v, u] = x

    put(f1, 17, 13, 100)  # suppressed by the larger (20, 14) of the next block inside its 7×7 window
    put(f1, 20, 14, 120)
    put(f1, 12, 20, 70)  # tie inside one block: the first in u-outer / v-inner scan order wins …
    put(f1, 13, 21, 70)  # … and an equal neighbour does not suppress it
    put(f1, 21, 25, -60)  # blob minimum …
    put(f2, 21, 25, 55)  # … and a corner maximum at the same pixel: both emitted, class 0 then 3
    put(f1, 31, 13, 90)  # kept: its window is clipped at u = 31, so the larger value at u = 32 is not seen
    put(f1, 32, 13, 200)  # outside every block
    put(f2, 13, 13, 49)  # below tau = 50
    put(f2, 25, 25, -50)  # exactly −tau: accepted
    put(f2, 17, 29, 80)  # equal maxima in neighbouring blocks: both kept
    put(f2, 20, 30, 80)

    u, v, c = block_nms(f1, f2, n=3, margin=9, tau=50)
    got = list(zip(u.tolist(), v.tolist(), c.tolist()))
    expected = [
        (12, 20, 1),  # block (12, 20)
        (17, 29, 3),  # block (16, 28)
        (20, 14, 1),  # block (20, 12)
        (21, 25, 0),  # block (20, 24)
        (21, 25, 3),
        (20, 30, 3),  # block (20, 28)
        (25, 25, 2),  # block (24, 24)
        (31, 13, 1),  # block (28, 12)
    ]
    assert got == expected


def test_block_nms_empty_when_image_too_small_or_flat():
    f = np.zeros((41, 41), np.int16)
    assert len(block_nms(f, f, 3, 9, 50)[0]) == 0
    tiny = np.full((20, 20), 500, np.int16)  # 20 − 3 − 9 = 8 < 12: no block fits
    assert len(block_nms(tiny, tiny, 3, 9, 50)[0]) == 0


def test_sparse_block_size_uses_larger_blocks():
    # with n = 9 the block origins are 18, 28 (u0 < 60 − 9 − 9 = 42 → 18, 28, 38): a single peak per block
    f1 = np.zeros((60, 60), np.int16)
    f1[20, 20] = 100
    f1[25, 25] = 90  # same 10×10 block as (20, 20): not the block maximum
    u, v, c = block_nms(f1, np.zeros_like(f1), 9, 9, 50)
    assert list(zip(u.tolist(), v.tolist(), c.tolist())) == [(20, 20, 1)]
