"""Per-channel response fits and the residual diagnostics of expoctl.camera.calibration (used by
benchmarks/memorial_reexposure.py), on synthetic inputs with known answers."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from expoctl.camera.calibration import (
    ChannelResponse, ParametricResponse, adc_code_lut, estimate_noise_sigma, fit_parametric_response,
    local_shift_fit, rmse_after_code_bias, rmse_percent)
from expoctl.camera.sensor import SensorConfig

GAMMAS = (2.7, 2.1, 2.3)       # per-channel curves like the Memorial scan's
OFFSETS = (-10.0, 0.0, 8.0)    # output pedestals, codes
SCALES = (4.0, 2.0, 3.0)       # relative exposure reaching code 255 in each channel (arbitrary per-channel units)


def per_channel_curve() -> np.ndarray:
    """Exact inverse curves X_c(z) = s_c·((z/255 − o_c)/(1 − o_c))^γ_c, (256, 3); codes below the pedestal → tiny."""
    z = np.arange(256) / 255.0
    cols = []
    for g, o, s in zip(GAMMAS, OFFSETS, SCALES):
        o = o / 255.0
        y = np.maximum((z - o) / (1.0 - o), 1e-6)
        cols.append(s * y ** g)
    return np.stack(cols, axis=1)


def test_per_channel_fit_recovers_each_channels_curve():
    fit, x_fs, info = fit_parametric_response(per_channel_curve(), "gamma", fit_gamma=True, fit_offset=True,
                                              per_channel=True)
    assert isinstance(fit, ChannelResponse)
    assert [r.gamma for r in fit.responses] == pytest.approx(GAMMAS, abs=1e-3)
    assert [255 * r.offset for r in fit.responses] == pytest.approx(OFFSETS, abs=0.05)
    assert x_fs == pytest.approx(max(SCALES), rel=1e-3)
    assert fit.gains == pytest.approx([max(SCALES) / s for s in SCALES], rel=1e-3)  # ≥ 1: no channel needs x > 1
    assert info["fit_rmse_codes"] < 0.01
    # as x → code: the recovered X(z) of every channel maps back to z
    z = [40, 128, 220]
    x = per_channel_curve()[z] / x_fs
    np.testing.assert_allclose(fit.code(x), np.repeat(np.array(z, float)[:, None], 3, axis=1), atol=0.02)


def test_shared_fit_cannot_follow_different_channel_curves_but_per_channel_can():
    curve = per_channel_curve()
    _, _, shared = fit_parametric_response(curve, "gamma", True, True)
    _, _, per = fit_parametric_response(curve, "gamma", True, True, per_channel=True)
    assert shared["fit_rmse_codes"] > 1.0 > 100 * per["fit_rmse_codes"]


def test_channel_response_runs_through_the_adc_lut():
    cfg = SensorConfig()
    resp = ChannelResponse(tuple(ParametricResponse("gamma", g, o / 255) for g, o in zip(GAMMAS, OFFSETS)),
                           (1.0, 2.0, 1.0))
    lut = adc_code_lut(cfg, resp)
    assert lut.shape == (cfg.adc_max_dn + 1, 3)
    full = cfg.adc_max_dn
    assert lut[full, 0] == 255 and lut[full, 2] == 255
    # the green channel's gain of 2 reaches 255 at half the linear range
    half = int(np.ceil(cfg.black_level_dn + 0.5 * (cfg.adc_max_dn - cfg.black_level_dn)))
    assert lut[half, 1] == 255 and lut[half, 0] < 255
    with pytest.raises(ValueError):
        resp.code(np.zeros(4))


def test_noise_sigma_of_a_smooth_image_with_known_noise():
    """A smooth (planar + slow sine) image with white Gaussian noise σ = 2 codes: recovered within 5 %; without
    noise the estimate is near zero (the kernel cancels planar signals)."""
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[:256, :256]
    clean = 60 + 0.3 * xx + 0.2 * yy + 5 * np.sin(xx / 40.0)
    img = np.stack([clean + s * rng.standard_normal(clean.shape) for s in (2.0, 2.0, 1.0)], axis=-1)
    sigma = estimate_noise_sigma(img)
    assert sigma == pytest.approx([2.0, 2.0, 1.0], rel=0.05)
    assert np.all(estimate_noise_sigma(np.repeat(clean[..., None], 3, -1)) < 0.02)
    mask = np.zeros(img.shape, bool)
    mask[:128] = True
    assert estimate_noise_sigma(img, mask) == pytest.approx([2.0, 2.0, 1.0], rel=0.07)


def test_code_bias_removal():
    """An error that depends only on the real code is removed exactly; independent noise is not."""
    rng = np.random.default_rng(1)
    real = rng.integers(21, 250, (64, 64, 3)).astype(np.uint8)
    mask = np.ones(real.shape, bool)
    pred = real + 0.02 * (real.astype(float) - 128.0) + 3.0  # a tone-curve error
    assert rmse_percent(pred, real, mask) > 0.5
    assert rmse_after_code_bias(pred, real, mask) == pytest.approx(0.0, abs=1e-9)
    noise = rng.standard_normal(real.shape) * 2.55  # 1 % of full scale
    assert rmse_after_code_bias(pred + noise, real, mask) == pytest.approx(1.0, rel=0.05)


def test_local_shift_fit_recovers_block_translations():
    """A smooth texture and the same texture translated (bilinear, the fit's own interpolation) by a different
    sub-pixel shift in each half: the block fit finds each half's shift within 0.05 px and the RMSE falls by more
    than 5×; blocks without samples get NaN and are left as they were."""
    rng = np.random.default_rng(2)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (128, 128)), (0, 0), 3)
    tex = 30 + 200 * (tex - tex.min()) / np.ptp(tex)
    pred = np.repeat(tex[..., None], 3, -1).astype(np.float32)
    yy, xx = np.mgrid[:128, :128].astype(np.float32)
    true = {0: (0.4, -0.3), 1: (-0.2, 0.5)}  # real(x) = pred(x + s) in the top / bottom half
    real = np.empty_like(pred)
    for half, (sx, sy) in true.items():
        rows = slice(64 * half, 64 * (half + 1))
        real[rows] = cv2.remap(pred, xx[rows] + sx, yy[rows] + sy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mask = np.zeros(pred.shape, bool)
    mask[4:-4, 4:-4] = True
    shifted, shifts = local_shift_fit(pred, real, mask, tile=32)
    assert shifts.shape == (4, 4, 2)
    for half, s in true.items():
        np.testing.assert_allclose(shifts[2 * half:2 * half + 2, 1:3].reshape(-1, 2), [s] * 4, atol=0.05)
    assert rmse_percent(shifted, real, mask) < rmse_percent(pred, real, mask) / 5
    empty, none = local_shift_fit(pred, real, np.zeros(pred.shape, bool))
    assert np.isnan(none).all()
    np.testing.assert_array_equal(empty, pred)


def test_local_shift_fit_edge_blocks_when_tile_does_not_divide_the_image():
    """A 100×72 image with 32-px tiles has 4×3 blocks whose last row / column are 4 / 8 px: every block, the clipped
    ones included, finds the one global shift (0.3, −0.2) within 0.05 px, and the result keeps the image's shape.
    (Before the fix the clipped blocks' pixel grids were tile-sized and the reshape failed.)"""
    rng = np.random.default_rng(5)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (100, 72)), (0, 0), 3)
    tex = 30 + 200 * (tex - tex.min()) / np.ptp(tex)
    pred = np.repeat(tex[..., None], 3, -1).astype(np.float32)
    yy, xx = np.mgrid[:100, :72].astype(np.float32)
    real = cv2.remap(pred, xx + 0.3, yy - 0.2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    mask = np.zeros(pred.shape, bool)
    mask[2:-2, 2:-2] = True
    shifted, shifts = local_shift_fit(pred, real, mask, tile=32, min_samples=20)
    assert shifted.shape == pred.shape
    assert shifts.shape == (4, 3, 2)
    np.testing.assert_allclose(shifts.reshape(-1, 2), [(0.3, -0.2)] * 12, atol=0.05)
