"""Response recovery, merge and re-exposure helpers on a synthetic bracketed stack with a known camera response."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from expoctl.camera.calibration import (
    ParametricResponse, adc_code_lut, fit_parametric_response, load_bracketed_stack, merge_radiance,
    monotone_log_response, noise_free_codes, plateau_brackets, recover_response, rmse_percent, valid_mask)
from expoctl.camera.sensor import SensorConfig
from expoctl.errors import InputError

TIMES_S = np.array([1 / 64, 1 / 16, 1 / 4, 1.0, 4.0])
TRUE = ParametricResponse("gamma", 2.2, 0.0)  # code = 255·x^(1/2.2), x = radiance·t (saturates at x = 1)


def synthetic_stack(seed: int = 0):
    rng = np.random.default_rng(seed)
    # log-uniform radiance over ~3.5 decades so every code range is visited by some bracket
    radiance = (10.0 ** rng.uniform(-3.0, 0.6, (48, 64, 3))).astype(np.float32)
    images = [np.clip(np.rint(TRUE.code(radiance * t)), 0, 255).astype(np.uint8) for t in TIMES_S]
    return radiance, images


def test_recovered_response_and_merge_follow_the_true_curve():
    radiance, images = synthetic_stack()
    resp = recover_response(images, TIMES_S, samples=40)
    g = monotone_log_response(resp)
    assert np.all(np.diff(g, axis=0) > 0)
    # the true inverse response is X(z) ∝ (z/255)^2.2: ln X(200) − ln X(50) is known up to the free scale
    expected = 2.2 * np.log(200 / 50)
    assert g[200] - g[50] == pytest.approx(np.full(3, expected), rel=0.08)
    merged = merge_radiance(images, TIMES_S, resp)
    ratio = merged / radiance  # relative radiance: equal up to one scale per channel
    mid = (radiance > 1e-2) & (radiance < 1.0)
    for c in range(3):
        r = ratio[..., c][mid[..., c]]
        assert np.std(np.log(r)) < 0.1


def test_parametric_fit_recovers_gamma_and_noise_free_reexposure_matches():
    radiance, images = synthetic_stack(1)
    # exact inverse response of the synthetic camera (X = (z/255)^2.2), as the Debevec curve would give it
    x_true = np.repeat(((np.arange(256) + 0.5) / 255.5)[:, None] ** 2.2, 3, axis=1)
    fit, x_fs, info = fit_parametric_response(x_true, "gamma", fit_gamma=True, fit_offset=True)
    assert fit.gamma == pytest.approx(2.2, rel=0.05) and abs(fit.offset) < 0.02
    assert x_fs == pytest.approx(1.0, rel=0.05) and info["fit_rmse_codes"] < 1.0
    cfg = SensorConfig()
    lut = adc_code_lut(cfg, fit)
    k = 2  # re-expose bracket 1/4 s with κ = 1/x_fs (x = R·t / x_fs)
    pred = noise_free_codes(radiance, TIMES_S[k], 1.0 / x_fs, cfg, lut)
    mask = valid_mask(images[k])
    assert rmse_percent(pred, images[k], mask) < 1.0


def test_valid_mask_plateau_and_rmse():
    dark = np.full((8, 8, 3), 15, np.uint8)
    mid = np.full((8, 8, 3), 120, np.uint8)
    sat = np.full((8, 8, 3), 255, np.uint8)
    assert not valid_mask(dark).any() and valid_mask(mid).all() and not valid_mask(sat).any()
    assert plateau_brackets([mid, dark, sat]) == [1, 2]
    assert rmse_percent(mid + 51, mid, valid_mask(mid)) == pytest.approx(20.0)
    with pytest.raises(ValueError):
        rmse_percent(dark, dark, valid_mask(dark))


def test_load_bracketed_stack_reads_rgb_and_names_bad_rows(tmp_path):
    img = np.zeros((4, 5, 3), np.uint8)
    img[..., 0] = 200  # red channel in RGB
    for name in ("a.png", "b.png", "c.png"):
        cv2.imwrite(str(tmp_path / name), img[..., ::-1])
    (tmp_path / "exposure_times.txt").write_text("# file seconds\na.png 1\nb.png 0.5\nc.png 0.25\n")
    images, times, names = load_bracketed_stack(tmp_path)
    assert names == ["a.png", "b.png", "c.png"] and times.tolist() == [1.0, 0.5, 0.25]
    assert images[0][0, 0].tolist() == [200, 0, 0]
    (tmp_path / "exposure_times.txt").write_text("a.png 1\nb.png -2\nc.png 0.25\n")
    with pytest.raises(InputError, match=r"exposure_times.txt:2: exposure time must be positive"):
        load_bracketed_stack(tmp_path)
    (tmp_path / "exposure_times.txt").write_text("a.png 1\nmissing.png 0.5\nc.png 0.25\n")
    with pytest.raises(InputError, match="cannot read image"):
        load_bracketed_stack(tmp_path)
    with pytest.raises(InputError, match="exposure list not found"):
        load_bracketed_stack(tmp_path / "nowhere")
