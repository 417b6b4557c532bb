"""The shot-noise shortcut (moment-matched Gaussian above `poisson_exact_below` electrons) is validated against exact
Poisson draws: same mean and variance, and a CDF within 2 % everywhere (two-sample Kolmogorov–Smirnov statistic)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from expoctl.camera.sensor import _shot_and_read_noise

N = 200_000
READ_NOISE_E = 2.8  # the default σ_d; it smooths the integer lattice of the Poisson law


def exact(mu: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.poisson(mu, N) + READ_NOISE_E * rng.standard_normal(N)


@pytest.mark.parametrize("mu_e", [0.5, 4.0, 10.0, 15.0, 60.0, 5000.0])
def test_shot_and_read_noise_matches_exact_poisson(mu_e):
    approx = _shot_and_read_noise(np.full(N, mu_e, np.float32), np.random.default_rng(1), 10.0, READ_NOISE_E)
    ref = exact(mu_e, 2)
    sd_mean = np.sqrt((mu_e + READ_NOISE_E ** 2) / N)
    assert abs(approx.mean() - mu_e) < 5 * sd_mean
    assert approx.var() == pytest.approx(mu_e + READ_NOISE_E ** 2, rel=0.02)
    # below the threshold the draws are exact; just above it the Gaussian's missing skew (1/√μ) costs < 2 % in CDF
    assert stats.ks_2samp(approx, ref).statistic < 0.02


def test_small_means_are_integer_electrons_without_read_noise():
    out = _shot_and_read_noise(np.full(1000, 3.0, np.float32), np.random.default_rng(0), 10.0, 0.0)
    np.testing.assert_array_equal(out, np.rint(out))

