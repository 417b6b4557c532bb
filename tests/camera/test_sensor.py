"""The sensor obeys the EMVA-1288 relations it is built from (photon transfer, reciprocity, saturation)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from expoctl.camera.sensor import Sensor, SensorConfig
from expoctl.errors import ConfigError, InputError

H, W = 64, 64


def flat(level_cd_m2: float) -> np.ndarray:
    return np.full((H, W, 3), level_cd_m2, np.float32)


def test_photons_per_lux_second_matches_spec():
    cfg = SensorConfig()
    per_lux_s = cfg.photons_per_cd_m2_s() * 4 * cfg.f_number ** 2 / (math.pi * cfg.lens_transmission)
    assert per_lux_s == pytest.approx(48.7e3, rel=0.01)  # simulator spec: ≈ 48.7k photons per lux·s at 3.45 µm


def test_photon_transfer_recovers_system_gain_read_noise_and_full_well():
    """EMVA-1288 photon transfer: temporal variance of (A − B)/√2 against the mean signal is a line of slope K and
    intercept K²σ_d² (plus quantisation 1/12 DN²); the signal saturates at K·full well."""
    cfg = SensorConfig(prnu=0.0, dsnu_e=0.0, black_level_fraction=0.02)
    sensor = Sensor(cfg, H, W, seed=1)
    gain_db = 12.0  # K = 4 × K₀: read noise well above quantisation
    k = cfg.k0_dn_per_e * 10 ** (gain_db / 20)
    means, variances = [], []
    exposure = 1000.0
    for level in np.geomspace(0.5, 25.0, 10):  # up to ~70 % of the ADC range at this gain
        a = sensor.capture_raw(flat(level), exposure, gain_db, np.random.default_rng(int(level * 1000)))
        b = sensor.capture_raw(flat(level), exposure, gain_db, np.random.default_rng(int(level * 1000) + 7))
        means.append(0.5 * (a.mean() + b.mean()) - cfg.black_level_dn)
        variances.append(np.var(a - b) / 2)
    dark_a = sensor.capture_raw(flat(0.0), exposure, gain_db, np.random.default_rng(3))
    dark_b = sensor.capture_raw(flat(0.0), exposure, gain_db, np.random.default_rng(4))
    dark_var = np.var(dark_a - dark_b) / 2
    slope, _ = np.polyfit(means, variances, 1)
    assert slope == pytest.approx(k, rel=0.05)
    read_noise_e = math.sqrt(max(dark_var - 1 / 12, 0)) / k
    assert read_noise_e == pytest.approx(cfg.read_noise_e, rel=0.05)


def test_full_well_and_adc_saturation():
    """With K·FW below the ADC range the full well is the limit; with more gain the ADC clips first, at 1/gain of the
    luminance (saturation in electrons falls as 1/gain)."""
    cfg = SensorConfig(system_gain_dn_per_e=0.3, prnu=0.0, dsnu_e=0.0)  # 0.3 × 10500 + black ≈ 3211 DN < 4095
    sensor = Sensor(cfg, H, W, seed=1)
    bright = sensor.capture_raw(flat(1e6), 30000.0, 0.0, np.random.default_rng(5))
    full_well_e = (np.median(bright) - cfg.black_level_dn) / cfg.k0_dn_per_e
    assert full_well_e == pytest.approx(cfg.full_well_e, rel=0.05)
    assert bright.max() < cfg.adc_max_dn
    clipped = sensor.capture_raw(flat(1e6), 30000.0, 12.0, np.random.default_rng(5))
    assert np.all(clipped == cfg.adc_max_dn)
    sat0, sat12 = sensor.saturation_luminance_cd_m2(1000, 0.0), sensor.saturation_luminance_cd_m2(1000, 12.0)
    assert sat12 < sat0
    assert sat12 == pytest.approx((cfg.adc_max_dn - cfg.black_level_dn) / (cfg.k0_dn_per_e * 10 ** 0.6)
                                  / (cfg.photons_per_cd_m2_s() * 1e-3 * cfg.quantum_efficiency), rel=1e-6)


def test_reciprocity_equal_mean_different_noise():
    """(t, g) and (2t, g − 6.02 dB) collect the same DN on average; the longer exposure has less relative noise."""
    sensor = Sensor(SensorConfig(prnu=0.0, dsnu_e=0.0), H, W, seed=2)
    scene = flat(2.0)
    short = sensor.capture_raw(scene, 2000.0, 18.0, np.random.default_rng(1))
    long = sensor.capture_raw(scene, 4000.0, 18.0 - 20 * math.log10(2), np.random.default_rng(2))
    assert short.mean() == pytest.approx(long.mean(), rel=0.01)
    # Twice the electrons at half the gain. In DN: σ_short = K·√(μ + σ_d²), σ_long = (K/2)·√(2μ + σ_d²).
    mu = float(sensor.mean_electrons(scene, 2000.0).mean())
    sd2 = sensor.cfg.read_noise_e ** 2
    expected = 2 * math.sqrt(mu + sd2) / math.sqrt(2 * mu + sd2)
    assert short.std() / long.std() == pytest.approx(expected, rel=0.05)
    assert expected > 1.3  # a real difference: gain and exposure are not interchangeable


def test_black_level_and_dark_frame():
    cfg = SensorConfig()
    sensor = Sensor(cfg, H, W, seed=3)
    dark = sensor.capture_raw(flat(0.0), 75.0, 0.0, np.random.default_rng(0))
    assert dark.mean() == pytest.approx(cfg.black_level_dn, abs=0.5)
    img = sensor.capture(flat(0.0), 75.0, 0.0, np.random.default_rng(0))
    assert img.mean() < 3  # black level is subtracted before the response curve


def test_gain_lowers_saturation_luminance():
    sensor = Sensor(SensorConfig(), H, W)
    assert sensor.saturation_luminance_cd_m2(1000, 6.02) == pytest.approx(
        sensor.saturation_luminance_cd_m2(1000, 0.0) / 2, rel=0.01)


def test_capture_equals_raw_path_and_is_deterministic():
    sensor = Sensor(SensorConfig(), H, W, seed=4)
    scene = np.random.default_rng(0).uniform(0, 30, (H, W, 3)).astype(np.float32)
    scene[:8] = 0.001  # dark rows take the exact Poisson branch
    fused = sensor.capture(scene, 8000.0, 6.0, np.random.default_rng(9))
    reference = sensor.raw_to_8bit(sensor.capture_raw(scene, 8000.0, 6.0, np.random.default_rng(9)))
    np.testing.assert_array_equal(fused, reference)
    np.testing.assert_array_equal(fused, sensor.capture(scene, 8000.0, 6.0, np.random.default_rng(9)))
    assert not np.array_equal(fused, sensor.capture(scene, 8000.0, 6.0, np.random.default_rng(10)))
    # fixed-pattern noise belongs to the unit: same seed, same maps
    np.testing.assert_array_equal(Sensor(SensorConfig(), H, W, seed=4)._gain_map, sensor._gain_map)


@pytest.mark.parametrize("exposure,gain,words", [
    (15.0, 0.0, "exposure_us"), (31000.0, 0.0, "exposure_us"), (float("nan"), 0.0, "exposure_us"),
    (1000.0, -1.0, "gain_db"), (1000.0, float("nan"), "gain_db"), (1000.0, 31.0, "gain_db")])
def test_bad_settings_raise(exposure, gain, words):
    with pytest.raises(InputError, match=words):
        Sensor(SensorConfig(), H, W).capture(flat(1.0), exposure, gain, np.random.default_rng(0))


@pytest.mark.parametrize("d,key", [
    ({"full_well_e": -5}, "sensor.full_well_e"), ({"quantum_efficiency": 1.5}, "sensor.quantum_efficiency"),
    ({"adc_bits": 4}, "sensor.adc_bits"), ({"f_nmuber": 2}, "sensor.f_nmuber"),
    ({"read_noise_e": float("nan")}, "sensor.read_noise_e"), ({"response_curve": "log"}, "sensor.response_curve")])
def test_bad_config_names_key(d, key):
    with pytest.raises(ConfigError) as exc:
        SensorConfig.from_dict(d)
    assert exc.value.key == key


def test_randomised_stays_within_amplitude():
    base = SensorConfig()
    r = base.randomised(np.random.default_rng(0), 0.15)
    for name in ("full_well_e", "read_noise_e", "prnu", "dsnu_e", "black_level_fraction"):
        assert abs(getattr(r, name) / getattr(base, name) - 1) <= 0.15
    assert r != base


def _serial_raw_reference(sensor, lum, exposure_us, gain_db, rng):
    """The noise model in plain numpy, consuming the draws in raster order (what the compiled kernel must reproduce
    exactly): one normal per pixel-channel, then one uniform per exact-Poisson pixel-channel in order."""
    cfg = sensor.cfg
    scale = np.float32(float(sensor._photons_per_cd_m2_us) * exposure_us * cfg.quantum_efficiency)
    mu = np.maximum(lum * scale * sensor._gain_map + sensor._dark_map, np.float32(0.0)).ravel()
    z = rng.standard_normal(lum.shape, dtype=np.float32).ravel()
    small = np.flatnonzero(mu < np.float32(cfg.poisson_exact_below))
    u = rng.random(max(small.size, 1), dtype=np.float32)[:small.size]
    e = (mu + np.sqrt(mu + np.float32(cfg.read_noise_e) ** 2) * z).astype(np.float32)
    m = mu[small]
    p = np.exp(-m)  # inverse-transform Poisson, vectorised over the small-mean pixels
    c, n = p.copy(), np.zeros(small.size, np.float32)
    for k in range(1, 201):
        go = u > c
        if not go.any():
            break
        n[go] += 1
        p = np.where(go, p * m / k, p)
        c = np.where(go, c + p, c)
    e[small] = n + np.float32(cfg.read_noise_e) * z[small]
    k_dn = np.float32(cfg.k0_dn_per_e * 10.0 ** (gain_db / 20.0))
    dn = np.rint(np.minimum(e, np.float32(cfg.full_well_e)) * k_dn + np.float32(cfg.black_level_dn))
    return np.clip(dn, 0, cfg.adc_max_dn).reshape(lum.shape)


def test_compiled_kernel_equals_numpy_reference_draw_for_draw():
    # A log-normal scene from ~0.01 to ~1000 e- mixes exact-Poisson and Gaussian pixels throughout, so any change to
    # which draw feeds which pixel (or to either branch) shows.
    sensor = Sensor(SensorConfig(), 64, 96, seed=5)
    rng = np.random.default_rng(11)
    per_cd_m2 = float(sensor._photons_per_cd_m2_us) * 5000.0 * sensor.cfg.quantum_efficiency
    lum = (np.exp(rng.normal(0.0, 2.0, (64, 96, 3))) * 10.0 / per_cd_m2).astype(np.float32)
    got = sensor.capture_raw(lum, 5000.0, 6.0, np.random.default_rng(3))
    want = _serial_raw_reference(sensor, lum, 5000.0, 6.0, np.random.default_rng(3))
    mu = sensor.mean_electrons(lum, 5000.0)
    assert 0.2 < float(np.mean(mu < sensor.cfg.poisson_exact_below)) < 0.8
    np.testing.assert_array_equal(got, want)


def test_per_channel_response_keys_reproduce_a_fitted_channel_response():
    """The sensor config keys of a `ChannelResponse` (what the Memorial fit gives) make the sensor's raw → 8-bit
    table exactly that model's, channel by channel; the config is YAML-safe (sequence.yaml records it)."""
    import yaml

    from expoctl.camera.calibration import ChannelResponse, ParametricResponse, adc_code_lut

    fit = ChannelResponse(tuple(ParametricResponse("gamma", g, o) for g, o in ((2.65, -0.106), (2.12, -0.026),
                                                                             (2.20, 0.013))), (1.024, 1.224, 1.0))
    cfg = SensorConfig.from_dict(fit.sensor_keys())
    sensor = Sensor(cfg, 2, 2, seed=0)
    codes = np.repeat(np.arange(cfg.adc_max_dn + 1)[:, None], 3, axis=1)
    table = sensor.raw_to_8bit(codes)
    np.testing.assert_array_equal(table, adc_code_lut(cfg, fit))
    assert not np.array_equal(table[:, 0], table[:, 1])  # really per channel
    assert SensorConfig.from_dict(yaml.safe_load(yaml.safe_dump(cfg.to_dict()))) == cfg


def test_capture_applies_each_channels_curve():
    """A flat grey scene through a per-channel response: each channel's code is that channel's curve at the mean
    signal (within shot noise), and `capture` equals `raw_to_8bit(capture_raw)` draw for draw."""
    keys = {"response_curve": "gamma", "response_gamma_rgb": [2.6, 2.1, 2.3], "response_pedestal_rgb": [0.0, 0.05, 0.1],
            "white_balance_rgb": [1.0, 1.3, 0.8]}
    sensor = Sensor(SensorConfig.from_dict(keys), H, W, seed=1)
    scene = flat(400.0)
    img = sensor.capture(scene, 8000.0, 0.0, np.random.default_rng(3))
    raw = sensor.capture_raw(scene, 8000.0, 0.0, np.random.default_rng(3))
    np.testing.assert_array_equal(img, sensor.raw_to_8bit(raw))
    cfg = sensor.cfg
    x = (np.median(raw.reshape(-1, 3), axis=0) - cfg.black_level_dn) / (cfg.adc_max_dn - cfg.black_level_dn)
    expect = [255 * (p + (1 - p) * min(wb * xc, 1.0) ** (1 / g)) for xc, g, p, wb in
              zip(x, keys["response_gamma_rgb"], keys["response_pedestal_rgb"], keys["white_balance_rgb"])]
    np.testing.assert_allclose(np.median(img.reshape(-1, 3), axis=0), expect, atol=1.0)
