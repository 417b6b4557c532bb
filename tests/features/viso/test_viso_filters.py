"""Filter responses of the libviso2-style detector, with hand-computed values (spec §2–§3)."""

import numpy as np

from expoctl.features.viso.filters import (
    BLOB_KERNEL,
    CORNER_KERNEL,
    blob_corner,
    gradient_bytes,
    half_resolution,
    sobel_du_dv,
    sobel_raw,
)


def test_half_resolution_truncates_the_mean_and_drops_odd_edges():
    img = np.array([[1, 2, 9], [3, 5, 9], [7, 7, 9]], np.uint8)  # 3×3: last row and column dropped
    out = half_resolution(img)
    assert out.shape == (1, 1)
    assert out[0, 0] == 2  # (1 + 2 + 3 + 5) // 4 = 11 // 4
    big = np.full((4, 6), 255, np.uint8)
    assert (half_resolution(big) == 255).all()  # no uint8 overflow in the sum


def _vertical_step(left, right, size=11):
    img = np.full((size, size), right, np.uint8)
    img[:, : size // 2] = left  # columns 0..4 = left, 5.. = right
    return img


def test_sobel_u_sign_and_value_on_a_step():
    # darker left: at u = 5, Σ d·I = 1·0 + 2·0 + 0·64 − 2·64 − 1·64 = −192, times Σ s = 16 → −3072
    s_u, s_v = sobel_raw(_vertical_step(0, 64))
    assert s_u[5, 5] == -3072
    assert s_v[5, 5] == 0
    # brighter left is positive: at u = 5 only u−2, u−1 are bright: (1 + 2)·64·16 = 3072
    s_u, _ = sobel_raw(_vertical_step(64, 0))
    assert s_u[5, 5] == 3072
    assert s_u[5, 4] == (1 * 64 + 2 * 64 + 0 - 2 * 0 - 0) * 16 + 0  # at u = 4: u−2, u−1, u are bright, u+1.. dark
    du, _ = sobel_du_dv(_vertical_step(64, 0))
    assert du[5, 5] == 3072 // 128 + 128 == 152


def test_sobel_v_is_positive_when_the_top_is_brighter():
    img = np.zeros((11, 11), np.uint8)
    img[:5, :] = 10
    s_u, s_v = sobel_raw(img)
    assert s_v[5, 5] == (1 * 10 + 2 * 10) * 16 == 480
    assert s_u[5, 5] == 0
    _, dv = sobel_du_dv(img)
    assert dv[5, 5] == 131  # 480 >> 7 = 3


def test_gradient_bytes_floor_not_truncation():
    # a one-level step, darker left: S_u = −3·16 = −48, floor(−48/128) = −1 → 127 (truncation would give 128)
    du, _ = sobel_du_dv(_vertical_step(0, 1))
    assert du[5, 5] == 127
    du, _ = sobel_du_dv(_vertical_step(1, 0))
    assert du[5, 5] == 128  # +48 >> 7 = 0


def test_gradient_bytes_clipping():
    s = np.array([20000, 16383, 16255, 0, -1, -128, -129, -16384, -16385, -20000], np.int32)
    expected = [255, 255, 254, 128, 127, 127, 126, 0, 0, 0]
    assert gradient_bytes(s).tolist() == expected
    assert gradient_bytes(s).dtype == np.uint8


def test_blob_and_corner_on_an_impulse():
    img = np.zeros((15, 15), np.uint8)
    img[7, 7] = 10
    f1, f2 = blob_corner(img)
    assert f1.dtype == np.int16 and f2.dtype == np.int16
    assert f1[7, 7] == 80  # centre weight 8
    assert f1[7, 8] == 10 and f1[6, 6] == 10  # inner ring +1
    assert f1[7, 9] == -10 and f1[5, 5] == -10 and f1[9, 6] == -10  # outer ring −1
    assert f1[7, 10] == 0
    # corner: the impulse at offset (dx, dy) = (−1, −1) from (8, 8) falls in the top-left quadrant → +
    assert f2[8, 8] == 10
    assert f2[6, 6] == 10  # offset (+1, +1): bottom-right quadrant → +
    assert f2[8, 6] == -10  # pixel (6, 8): impulse at (dx, dy) = (+1, −1): top-right → −
    assert f2[6, 8] == -10
    assert f2[7, 8] == 0 and f2[8, 7] == 0  # middle row / column have weight 0
    assert f2[7, 7] == 0


def test_blob_corner_match_brute_force_correlation():
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (12, 13), dtype=np.uint8)
    f1, f2 = blob_corner(img)
    a = np.array([1, 1, 0, -1, -1])
    corner = np.outer(a, a)
    assert (CORNER_KERNEL == corner).all()
    for y in range(2, 10):
        for x in range(2, 11):
            patch = img[y - 2 : y + 3, x - 2 : x + 3].astype(np.int64)
            assert f1[y, x] == (patch * BLOB_KERNEL.astype(np.int64)).sum()
            assert f2[y, x] == (patch * corner).sum()
    s_u, s_v = sobel_raw(img)
    s = np.array([1, 4, 6, 4, 1])
    d = np.array([1, 2, 0, -2, -1])
    for y in range(2, 10):
        for x in range(2, 11):
            patch = img[y - 2 : y + 3, x - 2 : x + 3].astype(np.int64)
            assert s_u[y, x] == (patch * np.outer(s, d)).sum()  # kernel[dy][dx] = s[dy]·d[dx]
            assert s_v[y, x] == (patch * np.outer(d, s)).sum()


def test_one_pass_gradient_bytes_equal_the_encoding_of_the_sums():
    rng = np.random.default_rng(4)
    img = rng.integers(0, 256, (30, 41), dtype=np.uint8)
    img[10:20, 10:20] = 255  # strong edges
    du, dv = sobel_du_dv(img)
    s_u, s_v = sobel_raw(img)
    inner = (slice(2, -2), slice(2, -2))
    assert (du[inner] == gradient_bytes(s_u)[inner]).all() and (dv[inner] == gradient_bytes(s_v)[inner]).all()
    assert (du[:2] == 128).all() and (dv[:, -2:] == 128).all()  # border: "no gradient"
