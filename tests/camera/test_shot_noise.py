"""Shot and read noise of the compiled sensor kernel against exact Poisson draws: exact below
`poisson_exact_below` electrons (inverse-transform Poisson), moment-matched Gaussian above it; same mean and variance
and a CDF within 2 % everywhere (two-sample Kolmogorov–Smirnov statistic)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from expoctl.camera.sensor import Sensor, SensorConfig

READ_NOISE_E = 2.8  # the default σ_d; it smooths the integer lattice of the Poisson law
H, W = 200, 334  # ~200k samples per channel ×3


def electrons_frame(mu_e: float, read_noise_e: float, seed: int) -> np.ndarray:
    """Raw frame of a flat scene with mean `mu_e` electrons, read out at 1 DN per electron, no black level or FPN."""
    cfg = SensorConfig(prnu=0.0, dsnu_e=0.0, read_noise_e=read_noise_e, black_level_fraction=0.0, adc_bits=16,
                       full_well_e=60000.0, system_gain_dn_per_e=1.0)
    sensor = Sensor(cfg, H, W)
    exposure_us = 1000.0
    lum = mu_e / (cfg.photons_per_cd_m2_s() * 1e-6 * exposure_us * cfg.quantum_efficiency)
    return sensor.capture_raw(np.full((H, W, 3), lum, np.float32), exposure_us, 0.0, np.random.default_rng(seed)).ravel()


@pytest.mark.parametrize("mu_e", [0.5, 4.0, 9.5, 15.0, 60.0, 5000.0])
def test_shot_and_read_noise_matches_exact_poisson(mu_e):
    sim = electrons_frame(mu_e, READ_NOISE_E, 1)
    rng = np.random.default_rng(2)
    # exact reference, with the ADC's rounding and its clip at 0 DN
    ref = np.clip(np.rint(rng.poisson(mu_e, sim.size) + READ_NOISE_E * rng.standard_normal(sim.size)), 0, None)
    assert abs(sim.mean() - ref.mean()) < 5 * np.sqrt(2 * ref.var() / sim.size)
    assert sim.var() == pytest.approx(ref.var(), rel=0.03)
    assert stats.ks_2samp(sim, ref).statistic < 0.02


def test_small_means_are_integer_poisson_without_read_noise():
    sim = electrons_frame(3.0, 0.0, 0)
    np.testing.assert_array_equal(sim, np.rint(sim))
    values, counts = np.unique(sim, return_counts=True)
    p = stats.poisson.pmf(values, 3.0)
    assert np.allclose(counts / sim.size, p, atol=0.005)  # the law itself, value by value
