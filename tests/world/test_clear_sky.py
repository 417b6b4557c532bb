"""CIE skies (expoctl.world.clear_sky) against the ISO 15469 / CIE S 011 formulas, evaluated here by hand with
independent code; their horizontal illuminance against brute-force quadrature and the overcast closed form 7π/9·Lz;
the render kernel's sky pixels against the formula; the clear sky's normalisation to its defining measured ratio."""

import math

import numpy as np
import pytest

from expoctl.errors import ConfigError
from expoctl.world import RenderConfig, Renderer, load_city
from expoctl.world import clear_sky as cs
from expoctl.world.city import Conditions
from expoctl.world.shade import MAT_SKY

Y_RGB = np.array([0.2126, 0.7152, 0.0722])
# type 12 by hand: a = −1, b = −0.32, c = 10, d = −3, e = 0.45
PHI0_12 = 1.0 - math.exp(-0.32)  # φ(0) = 1 + a·e^b


def f12(chi):
    return 1.0 + 10.0 * (math.exp(-3.0 * chi) - math.exp(-1.5 * math.pi)) + 0.45 * math.cos(chi) ** 2


def _sun(elev_deg, az_deg=0.0):
    el, az = math.radians(elev_deg), math.radians(az_deg)
    return np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])


def test_indicatrix_and_gradation_at_their_defining_angles():
    for sky, (a, b, c, d, e) in cs.CIE_TYPES.items():
        assert cs.indicatrix(c, d, e, math.pi / 2) == pytest.approx(1.0, abs=1e-15)  # f(90°) = 1 by construction
        assert cs.indicatrix(c, d, e, 0.0) == pytest.approx(1.0 + c * (1.0 - math.exp(d * math.pi / 2)) + e, rel=1e-15)
        assert cs.gradation(a, b, 0.0) == 1.0  # the horizon: exp(b/0) → 0 for b < 0
        assert cs.gradation(a, b, 1.0) == pytest.approx(1.0 + a * math.exp(b), rel=1e-15)
    assert cs.indicatrix(10.0, -3.0, 0.45, 0.0) == pytest.approx(11.45 - 10.0 * math.exp(-1.5 * math.pi))


@pytest.mark.parametrize("elev", [15.0, 35.0, 45.0, 60.0])
def test_type_12_horizon_and_zenith_ratios(elev):
    zs = math.radians(90.0 - elev)
    sun = _sun(elev)
    norm = 1.0 / (f12(zs) * PHI0_12)
    # horizon (φ = 1) toward the sun (χ = elevation), across (χ = 90°), away (χ = 180° − elevation)
    dirs = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    expected = [f12(math.radians(elev)) * norm, 1.0 * norm, f12(math.pi - math.radians(elev)) * norm, 1.0]
    got = cs.relative_luminance("cie_12", sun, dirs)
    np.testing.assert_allclose(got, expected, rtol=1e-12)
    # the numba kernel's scalar version: same numbers
    for dvec, want in zip(dirs, expected):
        assert cs.general_sky_inline(-1.0, -0.32, 10.0, -3.0, 0.45, cs.normaliser("cie_12", zs), dvec[2],
                                     float(dvec @ sun)) == pytest.approx(want, rel=1e-12)
    if elev == 45.0:  # toward the sun at 45°: f(45°) cancels, L/Lz = 1/φ(0) = 1/(1 − e^−0.32) = 3.6516
        assert got[0] == pytest.approx(1.0 / PHI0_12, rel=1e-12) and got[0] == pytest.approx(3.6516, abs=1e-4)


def _brute_force(sky, sun, n_z=1500, n_az=3000, band_deg=90.0):
    """Midpoint rule in (zenith angle, azimuth): ∫ L/Lz cos Z dω, ∫ L/Lz dω, ∫ dω over elevations 0…band_deg."""
    z0 = math.radians(90.0 - band_deg)
    z = z0 + (np.arange(n_z) + 0.5) * ((math.pi / 2 - z0) / n_z)
    az = (np.arange(n_az) + 0.5) * (2 * math.pi / n_az)
    zz, aa = np.meshgrid(z, az, indexing="ij")
    dirs = np.stack([np.sin(zz) * np.cos(aa), np.sin(zz) * np.sin(aa), np.cos(zz)], axis=-1)
    d_omega = np.sin(zz) * ((math.pi / 2 - z0) / n_z) * (2 * math.pi / n_az)
    lum = cs.relative_luminance(sky, sun, dirs)
    return float((lum * np.cos(zz) * d_omega).sum()), float((lum * d_omega).sum()), float(d_omega.sum())


@pytest.mark.parametrize("sky,elev", [("cie_12", 10.0), ("cie_12", 40.0), ("cie_13", 25.0), ("cie_13", 55.0)])
def test_illuminance_integral_against_brute_force(sky, elev):
    # the brute force puts the sun at another azimuth (the integral must not care)
    e_bf, _, _ = _brute_force(sky, _sun(elev, 37.0))
    assert cs.illuminance_factor(sky, math.radians(90.0 - elev)) == pytest.approx(e_bf, rel=2e-4)
    _, lum, omega = _brute_force(sky, _sun(elev, 37.0), n_z=300, band_deg=cs.HORIZON_BAND_DEG)
    assert cs.horizon_band_factor(sky, math.radians(90.0 - elev)) == pytest.approx(lum / omega, rel=2e-4)


def test_overcast_closed_form():
    assert cs.illuminance_factor(cs.OVERCAST, 0.5) == 7.0 * math.pi / 9.0
    e_bf, _, _ = _brute_force(cs.OVERCAST, _sun(30.0), n_z=400, n_az=8)
    assert e_bf == pytest.approx(7.0 * math.pi / 9.0, rel=1e-5)
    c = Conditions(_sun(30.0), 0.0, 10000.0, True)
    assert c.sky_illuminance_lux == pytest.approx(7.0 * math.pi / 9.0 * 10000.0, rel=1e-15)


def test_clear_sky_level_meets_its_measured_ratio():
    """Lz is set so that the near-horizon band's mean luminance is 12 kcd/m² per 100 klux of global horizontal
    illuminance (sun + this sky); check that defining property with the brute-force integrals."""
    for sky, elev in (("cie_12", 35.0), ("cie_13", 50.0), ("cie_12", 12.0)):
        sun = _sun(elev, 200.0)
        lz = cs.clear_sky_zenith_cd_m2(sky, sun, 85000.0, 12000.0)
        e_sky = _brute_force(sky, sun)[0] * lz
        _, lum, omega = _brute_force(sky, sun, n_z=300, band_deg=10.0)
        band = lum / omega * lz
        assert band == pytest.approx(0.12 * (85000.0 * sun[2] + e_sky), rel=1e-3)
        c = Conditions(sun, 85000.0, lz, False, None, sky)
        assert c.sky_illuminance_lux == pytest.approx(e_sky, rel=2e-4)  # the sky that lights = the sky seen
    with pytest.raises(ValueError, match="no clear sky"):
        cs.clear_sky_zenith_cd_m2("cie_12", _sun(60.0), 85000.0, 1.0e6)


def test_traversal_conditions_and_config_keys():
    city = load_city("train")
    c = city.conditions(0, 0)
    assert not c.overcast and c.sky == "cie_12"
    # at a 32° sun the near-horizon sky lands inside the measured clear-sky range 8–16 kcd/m² per 100 klux
    zs = math.acos(c.sun_direction[2])
    band = cs.horizon_band_factor("cie_12", zs) * c.sky_zenith_cd_m2
    assert band * 1e5 / c.global_illuminance_lux == pytest.approx(12000.0, rel=1e-9)
    legacy = load_city({"base": "train", "traversal": {"clear_sky": "overcast_profile"}}).conditions(0, 0)
    assert legacy.sky == cs.OVERCAST and 9000.0 <= legacy.sky_zenith_cd_m2 <= 12000.0  # the drawn overcast Lz
    assert np.array_equal(legacy.sun_direction, c.sun_direction)  # same draws: only the sky differs
    with pytest.raises(ConfigError, match="world.city.traversal.clear_sky"):
        load_city({"base": "train", "traversal": {"clear_sky": "cie_99"}})
    for bad in (0.0, 26000.0):
        with pytest.raises(ConfigError, match="world.city.traversal.clear_sky_horizon_cd_m2_per_100klux"):
            load_city({"base": "train", "traversal": {"clear_sky_horizon_cd_m2_per_100klux": bad}})
    # the cap keeps every sun elevation solvable: the worst case, type 13 with the sun near the zenith
    sun = _sun(89.9)
    assert cs.clear_sky_zenith_cd_m2("cie_13", sun, 100000.0, 25000.0) > 0.0


def test_rendered_sky_pixels_follow_the_distribution():
    city = load_city("train")
    c = city.conditions(0, 0)
    r = Renderer(city, RenderConfig(width=96, height=72, hfov_deg=90.0), conditions=c)
    pose = city.pose_at_s(250.0, 0.0)
    pose[:3, :3] = pose[:3, :3] @ np.array([[1, 0, 0], [0, math.cos(1.0), -math.sin(1.0)],
                                            [0, math.sin(1.0), math.cos(1.0)]])  # pitch up ~57°
    out = r.render_full(pose, glare=False)
    sky = out["material"] == MAT_SKY
    assert sky.mean() > 0.5
    ys, xs = np.nonzero(sky)
    K = r.K
    rays = np.stack([(xs + 0.5 - K[0, 2]) / K[0, 0], (ys + 0.5 - K[1, 2]) / K[1, 1], np.ones(xs.size)], axis=-1)
    rays = rays @ pose[:3, :3].T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    want = c.sky_zenith_cd_m2 * cs.relative_luminance("cie_12", c.sun_direction, rays)
    # sky RGB is normalised to unit luminance Y; the sun disk (if in view) is excluded by the tolerance on few pixels
    got = out["luminance"][ys, xs] @ Y_RGB
    rel = np.abs(got - want) / want
    assert np.median(rel) < 1e-5 and np.percentile(rel, 99) < 1e-4
