"""SumLog transform: exact values on constructed images, gain invariance, 8-bit rescaling, grid tuning."""

import math

import numpy as np
import pytest
import skimage.data

from expoctl.errors import ConfigError
from expoctl.features.orb import OrbFrontEnd
from expoctl.features.sumlog import SumLogParams, score_sumlog_grid, sumlog, sumlog_range, sumlog_uint8, tune_sumlog


def test_exact_value_on_a_constant_image():
    img = np.empty((4, 5, 3), np.uint8)
    img[...] = (10, 100, 200)
    alpha, beta = (0.2, 0.5, 0.3), 2.0
    expected = 0.2 * math.log(12) + 0.5 * math.log(102) + 0.3 * math.log(202)
    np.testing.assert_allclose(sumlog(img, alpha, beta), expected, rtol=0, atol=1e-12)


def test_global_gain_adds_a_constant_when_beta_is_zero():
    rng = np.random.default_rng(0)
    img = rng.uniform(1, 200, (16, 16, 3))
    alpha = (0.25, 0.5, 0.25)
    for k in (0.1, 2.0, 7.5):
        diff = sumlog(k * img, alpha, 0.0) - sumlog(img, alpha, 0.0)
        # Σ α_c log(k I_c) = Σ α_c log I_c + (Σ α_c) log k at every pixel: the structure is unchanged
        np.testing.assert_allclose(diff, sum(alpha) * math.log(k), rtol=0, atol=1e-12)


def test_with_beta_the_gain_residual_is_exactly_the_offset_term():
    rng = np.random.default_rng(1)
    img = rng.uniform(0, 255, (8, 8, 3))
    alpha, beta, k = (0.3, 0.3, 0.4), 4.0, 3.0
    diff = sumlog(k * img, alpha, beta) - sumlog(img, alpha, beta)
    # log(kI+β) - log(I+β) = log k + log((kI+β)/(kI+kβ)): the second term → 0 for bright pixels, −log k at black
    residual = (np.log((k * img + beta) / (k * img + k * beta)) @ np.array(alpha))
    np.testing.assert_allclose(diff - sum(alpha) * math.log(k), residual, rtol=0, atol=1e-12)
    assert np.all(residual <= 0) and np.all(residual >= -math.log(k))


def test_uint8_range_mapping_is_fixed_and_exact():
    p = SumLogParams(alpha=(0.5, 0.25, 0.25), beta=2.0)
    lo, hi = sumlog_range(p.alpha, p.beta)
    assert lo == pytest.approx(math.log(2.0)) and hi == pytest.approx(math.log(257.0))
    img = np.zeros((3, 1, 3), np.uint8)
    img[1] = 255
    img[2] = 40
    out = sumlog_uint8(img, p)
    expected_mid = round(255 * (math.log(42) - math.log(2)) / (math.log(257) - math.log(2)))
    assert out.dtype == np.uint8 and out[:, 0].tolist() == [0, 255, expected_mid]
    # image-independent: the same RGB maps to the same grey whatever else is in the picture
    bigger = np.concatenate([img, np.full((3, 1, 3), 90, np.uint8)], axis=1)
    assert np.array_equal(sumlog_uint8(bigger, p)[:, :1], out)


def test_range_with_negative_weight():
    lo, hi = sumlog_range((1.0, -0.5, 0.0), 1.0)
    assert lo == pytest.approx(0 - 0.5 * math.log(256)) and hi == pytest.approx(math.log(256) - 0)


def test_minmax_mode_stretches_each_image():
    img = np.zeros((2, 1, 3), np.uint8)
    img[0], img[1] = 50, 60
    out = sumlog_uint8(img, SumLogParams(beta=1.0, rescale="minmax"))
    assert out[:, 0].tolist() == [0, 255]
    assert not sumlog_uint8(np.full((2, 2, 3), 7, np.uint8), SumLogParams(rescale="minmax")).any()


def test_bad_parameters():
    with pytest.raises(ConfigError, match="alpha"):
        SumLogParams(alpha=(1, 0))
    with pytest.raises(ConfigError, match="alpha"):
        SumLogParams(alpha=(0, 0, 0))
    with pytest.raises(ConfigError, match="beta"):
        SumLogParams(beta=-1)
    with pytest.raises(ConfigError, match="rescale"):
        SumLogParams(rescale="clahe")
    with pytest.raises(ValueError, match="β > 0"):
        sumlog(np.zeros((2, 2, 3), np.uint8), (1, 1, 1), 0.0)
    with pytest.raises(ValueError, match="RGB"):
        sumlog(np.zeros((2, 2), np.uint8), (1, 1, 1), 1.0)


def _red_only_pairs():
    """Sequential pairs whose structure is only in the red channel (a photo panning 6 px/frame); G and B are flat."""
    photo = skimage.data.camera()  # 512×512 grey
    frames = []
    for t in range(3):
        rgb = np.full((384, 448, 3), 128, np.uint8)
        rgb[..., 0] = photo[60 : 60 + 384, 6 * t : 6 * t + 448]
        frames.append(rgb)
    return [(frames[0], frames[1]), (frames[1], frames[2])]


def test_tuning_picks_the_weights_that_see_the_structure():
    orb = OrbFrontEnd({"working_size": None, "count_nfeatures": 500, "match_nfeatures": 500})
    pairs = _red_only_pairs()
    alphas = [(0.0, 0.0, 1.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)]
    scores = score_sumlog_grid(pairs, orb, alphas, [1.0])
    totals = [total for _, total in scores]
    assert totals[0] == 0 and totals[2] == 0  # blue / green only: a flat image, no features at all
    assert totals[1] > 300  # red: a textured photo moving rigidly
    assert tune_sumlog(pairs, orb, alphas, [1.0]).alpha == (1.0, 0.0, 0.0)


def test_tuning_ties_go_to_the_first_grid_point():
    orb = OrbFrontEnd({"working_size": None, "count_nfeatures": 100, "match_nfeatures": 100})
    pairs = _red_only_pairs()
    best = tune_sumlog(pairs, orb, [(0.0, 0.0, 1.0), (0.0, 1.0, 0.0)], [1.0, 3.0])  # all zero
    assert best == SumLogParams(alpha=(0.0, 0.0, 1.0), beta=1.0)
    with pytest.raises(ValueError, match="at least one"):
        tune_sumlog([], orb, [(1, 0, 0)], [1.0])


def test_grid_config():
    from expoctl.features.sumlog import SumLogGrid

    g = SumLogGrid.from_dict({"alphas": [[1, 0, 0], [0.5, 0.5, 0]], "betas": [1, 4], "max_pairs": 10})
    assert g.alphas == ((1.0, 0.0, 0.0), (0.5, 0.5, 0.0)) and g.betas == (1.0, 4.0) and g.max_pairs == 10
    for bad, key in [({"alphas": [[1, 0]]}, "alphas"), ({"betas": []}, "betas"), ({"betas": [0.0]}, "betas"),
                     ({"rescale": "x"}, "rescale"), ({"max_pairs": 0}, "max_pairs"), ({"grid": 1}, "grid")]:
        with pytest.raises(ConfigError, match=f"features\\.sumlog\\.{key}"):
            SumLogGrid.from_dict(bad)
