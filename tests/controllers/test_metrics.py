"""Image metrics on constructed images with known values."""

import math

import numpy as np
import pytest

from expoctl.controllers import metrics as m


def test_metering_windows():
    rows, cols = m.metering_window((100, 100), "spot")  # √0.03 · 100 = 17.3 → 17 px centred
    assert (rows.stop - rows.start, cols.stop - cols.start) == (17, 17) and rows.start == 41
    rows, cols = m.metering_window((100, 200), "partial")  # √0.11 → 33 × 66
    assert (rows.stop - rows.start, cols.stop - cols.start) == (33, 66)
    rows, cols = m.metering_window((100, 200), "average", roi=(0.5, 0.0, 1.0, 0.25))
    assert (rows, cols) == (slice(0, 25), slice(100, 200))


def test_luma_uses_rec601_weights():
    img = np.zeros((1, 3, 3), np.uint8)
    img[0, 0, 0] = img[0, 1, 1] = img[0, 2, 2] = 255
    assert m.luma_uint8(img).tolist() == [[76, 150, 29]]


def test_entropy_known_values():
    two = np.zeros((10, 10), np.uint8)
    two[:, 5:] = 255
    assert m.entropy_bits(two) == pytest.approx(1.0)  # two equiprobable levels: 1 bit → Shin's E = 1/8
    assert m.entropy_bits(np.full((7, 7), 42, np.uint8)) == 0.0
    assert m.entropy_bits(np.arange(256, dtype=np.uint8).reshape(16, 16)) == pytest.approx(8.0)
    four = np.repeat(np.array([0, 1, 2, 3], np.uint8), 4)
    assert m.entropy_bits(four) == pytest.approx(2.0)


def test_shim_map_endpoints_and_threshold():
    assert m.shim_map(0.06) == pytest.approx(0.0)
    assert m.shim_map(1.0) == pytest.approx(1.0)
    assert m.shim_map(0.03) == 0.0  # below δ: treated as noise
    v = m.shim_map(np.linspace(0.06, 1, 50))
    assert np.all(np.diff(v) > 0)
    # Zhang's constants: same endpoints
    assert m.shim_map(0.11, lam=10, delta=0.11) == pytest.approx(0.0) and m.shim_map(1.0, 10, 0.11) == pytest.approx(1.0)
    mid = m.shim_map(0.5, lam=1e3, delta=0.06)
    assert mid == pytest.approx(math.log(1e3 * 0.44 + 1) / math.log(1e3 * 0.94 + 1))


def test_normalised_gradient_of_a_full_step():
    img = np.zeros((9, 10))
    img[:, 5:] = 255.0
    g = m.normalised_gradient(img)
    # a vertical 0→255 step: |gx| = 4·255 on the two columns beside it, gy = 0 → 1/√2 of the diagonal maximum
    assert g[:, 4].tolist() == pytest.approx([1 / math.sqrt(2)] * 9)
    assert g[:, 0].max() == 0.0 and g.max() <= 1.0


def test_shin_gradient_term_known_values():
    assert m.shin_gradient_term(np.zeros((50, 50))) == 0.0  # no gradient at all
    # vertical stripes 2 px on / 2 px off: every interior pixel has |gx| = 4·255 → mapped value shim_map(1/√2);
    # only the outermost columns (replicated border) are 0, so cell means are nearly equal and mean/std ≈ 24 → cap
    stripes = np.tile(np.array([0.0, 0.0, 255.0, 255.0]), (100, 25))
    assert m.shin_gradient_term(stripes) == 10.0
    half = stripes.copy()
    half[:, 48:] = 0.0  # texture in the left five grid columns only (the step's response stays in column 48)
    cells = m.cell_means(m.shim_map(m.normalised_gradient(half)), 10).ravel()
    expected = cells.mean() / cells.std(ddof=1)
    assert m.shin_gradient_term(half) == pytest.approx(expected)
    assert 0.9 < expected < 1.1  # half the cells at c, half near 0: mean/std ≈ √(99/100)


@pytest.mark.parametrize("sigma", [2.0, 5.0, 10.0])
def test_immerkaer_recovers_sigma_of_flat_image_plus_gaussian_noise(sigma):
    """256² pixels: the whole-image estimator's relative standard error is ≈ √(π/2 − 1)/√(N/4) ≈ 0.6 % (neighbouring
    kernel responses overlap, so ~N/4 independent terms) → 2 % is > 3 standard errors. Shin's mask keeps 10 % of
    the pixels (≈ 1.9 % standard error) → 7 %."""
    rng = np.random.default_rng(1)
    img = 128.0 + rng.normal(0.0, sigma, (256, 256))
    assert m.immerkaer_sigma(img, homogeneous_fraction=1.0, intensity_range=(-1e9, 1e9)) == pytest.approx(sigma, rel=0.02)
    assert m.immerkaer_sigma(img) == pytest.approx(sigma, rel=0.07)


def test_immerkaer_is_blind_to_planar_shading_and_robust_to_saturation():
    y, x = np.mgrid[0:64, 0:64].astype(np.float64)
    assert m.immerkaer_sigma(40 + 1.5 * x + 0.7 * y) == pytest.approx(0.0, abs=1e-9)
    assert m.immerkaer_sigma(np.full((32, 32), 255.0)) == 0.0  # falls back to the whole image: still finite
    assert m.immerkaer_sigma(np.zeros((2, 2))) == 0.0


@pytest.mark.parametrize("code", [0, 255])
def test_shin_score_is_finite_and_zero_on_flat_frames(code):
    score, g, e, n = m.shin_score(np.full((40, 60, 3), code, np.uint8))
    assert (score, g, e, n) == (0.0, 0.0, 0.0, 0.0)


def test_shin_score_penalises_noise():
    rng = np.random.default_rng(0)
    base = np.tile(np.linspace(40, 200, 80), (60, 1))
    clean = np.repeat(np.clip(np.rint(base), 0, 255).astype(np.uint8)[..., None], 3, axis=2)
    noisy = np.clip(np.rint(clean + rng.normal(0, 6, clean.shape)), 0, 255).astype(np.uint8)
    s_clean, *_ = m.shin_score(clean)
    s_noisy, _, _, n_noisy = m.shin_score(noisy)
    assert n_noisy == pytest.approx(6.0, rel=0.15)  # 80×60 per channel: a few % standard error + mask selection
    assert s_noisy < s_clean
