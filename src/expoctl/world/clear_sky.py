"""Sky luminance distributions: the CIE general sky (ISO 15469:2004 / CIE S 011/E:2003) for clear skies, the CIE
standard overcast sky for overcast ones, their horizontal illuminance, and the clear sky's absolute level.

CIE general sky, relative to the zenith (Z: zenith angle of the sky element, Zs: of the sun, χ: angle between the sky
element and the sun):
    L(Z, χ) / Lz = f(χ)·φ(Z) / (f(Zs)·φ(0))
    gradation  φ(Z) = 1 + a·exp(b / cos Z)          (φ(90°) = 1: b < 0, so exp(b / cos Z) → 0 at the horizon)
    indicatrix f(χ) = 1 + c·(exp(d·χ) − exp(d·π/2)) + e·cos²χ
Types used here (ISO 15469 Table 1; gradation group VI, indicatrix groups 4 and 5):
    12 'CIE standard clear sky, low luminance turbidity'  a = −1, b = −0.32, c = 10, d = −3, e = 0.45
    13 'CIE standard clear sky, polluted atmosphere'      a = −1, b = −0.32, c = 16, d = −3, e = 0.30
CIE standard overcast sky (Moon & Spencer 1942): L(Z) / Lz = (1 + 2 cos Z) / 3, horizontal illuminance (7π/9)·Lz.

Absolute level of a clear sky. The general sky fixes only ratios; the zenith luminance Lz is set so that the mean
luminance of the near-horizon sky — the band 0°…10° of elevation, all azimuths, solid-angle weighted, which is the sky
a driver sees around a tunnel portal — equals `horizon_cd_m2_per_100klux` per 100 klux of global horizontal
illuminance (direct sun on the horizontal + this sky's own diffuse horizontal illuminance). Default 12 kcd/m² per
100 klux: the middle of the measured clear-sky values of 8 kcd/m² (looking away from the sun) … 16 kcd/m² (toward it)
tabulated for high daylight levels (~100 klux) by van Bommel, Road Lighting (2015), Table 20.1, after CIE 88:2004.
With m = band mean / Lz and k = E_sky / Lz of the distribution (both depend only on the type and Zs):
    m·Lz = r·(E_sun,h + k·Lz)   →   Lz = r·E_sun,h / (m − r·k),   r = horizon_cd_m2_per_100klux / 1e5 (cd/m² per lux)
The sky's horizontal illuminance E_sky = k·Lz lights the outdoor surfaces (Conditions.sky_illuminance_lux), so the sky
the camera sees and the sky that lights the scene are the same distribution.

The `*_inline` functions are numba-inlinable scalar versions used by the render kernel (shade._sky); the numpy ones
serve set-up and tests.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

# ISO 15469 / CIE S 011 parameters (a, b, c, d, e)
CIE_TYPES = {
    "cie_12": (-1.0, -0.32, 10.0, -3.0, 0.45),  # CIE standard clear sky, low luminance turbidity
    "cie_13": (-1.0, -0.32, 16.0, -3.0, 0.30),  # CIE standard clear sky, polluted atmosphere
}
OVERCAST = "cie_overcast"
SKIES = (OVERCAST,) + tuple(CIE_TYPES)
HORIZON_BAND_DEG = 10.0  # the near-horizon band whose mean luminance sets a clear sky's level
# quadrature of the hemisphere for the integrals below: Gauss–Legendre in cos Z (the integrand is smooth in it; near
# the horizon exp(b/cos Z) is flat to all orders) × the midpoint rule in azimuth (periodic, so it converges fast except
# at the kink of exp(d·χ) at the sun; 1024 azimuths keep that error < 1e-5 relative, tests/world/test_clear_sky.py)
_N_COSZ, _N_AZ = 96, 1024


def gradation(a: float, b: float, cos_z):
    """φ(Z) = 1 + a·exp(b / cos Z); 1 at and below the horizon (cos Z ≤ 0; b < 0 for every CIE type)."""
    cz = np.asarray(cos_z, dtype=np.float64)
    safe = np.where(cz > 0.0, cz, 1.0)
    return np.where(cz > 0.0, 1.0 + a * np.exp(b / safe), 1.0)


def indicatrix(c: float, d: float, e: float, chi):
    """f(χ) = 1 + c·(exp(d·χ) − exp(d·π/2)) + e·cos²χ (χ: angle from the sun, rad)."""
    chi = np.asarray(chi, dtype=np.float64)
    return 1.0 + c * (np.exp(d * chi) - math.exp(d * math.pi / 2)) + e * np.cos(chi) ** 2


def normaliser(sky: str, sun_zenith_rad: float) -> float:
    """1 / (f(Zs)·φ(0)): the factor that makes L/Lz = 1 at the zenith."""
    a, b, c, d, e = CIE_TYPES[sky]
    return 1.0 / (float(indicatrix(c, d, e, sun_zenith_rad)) * float(gradation(a, b, 1.0)))


def relative_luminance(sky: str, sun: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """L / Lz for unit directions dirs (..., 3), world z up; sun: unit vector toward the sun. Below the horizon the
    horizon value (as the render kernel: the modelled ground hides it anyway)."""
    dirs = np.asarray(dirs, dtype=np.float64)
    cz = np.maximum(dirs[..., 2], 0.0)
    if sky == OVERCAST:
        return (1.0 + 2.0 * cz) / 3.0
    a, b, c, d, e = CIE_TYPES[sky]
    chi = np.arccos(np.clip(dirs @ np.asarray(sun, dtype=np.float64), -1.0, 1.0))
    zs = math.acos(max(-1.0, min(1.0, float(sun[2]))))
    return indicatrix(c, d, e, chi) * gradation(a, b, cz) * normaliser(sky, zs)


def _band_integrals(sky: str, sun_zenith_rad: float, cos_lo: float, cos_hi: float):
    """(∫ L/Lz·cos Z dω, ∫ L/Lz dω, ∫ dω) over the part of the sky with cos Z in [cos_lo, cos_hi] (sun at azimuth 0)."""
    x, w = np.polynomial.legendre.leggauss(_N_COSZ)
    cz = cos_lo + (cos_hi - cos_lo) * 0.5 * (x + 1.0)
    wz = w * 0.5 * (cos_hi - cos_lo)
    az = (np.arange(_N_AZ) + 0.5) * (2.0 * math.pi / _N_AZ)
    sz = np.sqrt(1.0 - cz * cz)
    dirs = np.stack([sz[:, None] * np.cos(az)[None, :], sz[:, None] * np.sin(az)[None, :],
                     np.broadcast_to(cz[:, None], (cz.size, az.size))], axis=-1)
    sun = np.array([math.sin(sun_zenith_rad), 0.0, math.cos(sun_zenith_rad)])
    lum = relative_luminance(sky, sun, dirs)
    d_omega = wz[:, None] * (2.0 * math.pi / _N_AZ)  # dω = d(cos Z)·dα
    return float((lum * cz[:, None] * d_omega).sum()), float((lum * d_omega).sum()), float(d_omega.sum() * _N_AZ)


@functools.lru_cache(maxsize=4096)
def illuminance_factor(sky: str, sun_zenith_rad: float) -> float:
    """E_sky / Lz: horizontal illuminance of the whole sky per unit zenith luminance (sr). Overcast: 7π/9 exactly."""
    if sky == OVERCAST:
        return 7.0 * math.pi / 9.0
    return _band_integrals(sky, sun_zenith_rad, 0.0, 1.0)[0]


@functools.lru_cache(maxsize=4096)
def horizon_band_factor(sky: str, sun_zenith_rad: float) -> float:
    """Mean L / Lz over the near-horizon band (elevation 0…HORIZON_BAND_DEG, all azimuths, per solid angle)."""
    _, lum, omega = _band_integrals(sky, sun_zenith_rad, 0.0, math.sin(math.radians(HORIZON_BAND_DEG)))
    return lum / omega


def clear_sky_zenith_cd_m2(sky: str, sun: np.ndarray, sun_normal_lux: float, horizon_cd_m2_per_100klux: float) -> float:
    """Zenith luminance (cd/m²) of a clear sky whose near-horizon band luminance is horizon_cd_m2_per_100klux per
    100 klux of global horizontal illuminance (module docstring); sun above the horizon."""
    zs = math.acos(max(-1.0, min(1.0, float(sun[2]))))
    k, m = illuminance_factor(sky, zs), horizon_band_factor(sky, zs)
    r = horizon_cd_m2_per_100klux / 1.0e5
    if not m > r * k:
        raise ValueError(f"no clear sky has a near-horizon band of {horizon_cd_m2_per_100klux} cd/m² per 100 klux "
                         f"for {sky} at sun zenith {math.degrees(zs):.1f}° (band/zenith {m:.3f} <= r·E/Lz {r * k:.3f})")
    return r * sun_normal_lux * max(float(sun[2]), 0.0) / (m - r * k)


# ------------------------------------------------------------------ render kernel (numba, inlined into shade._sky)
@njit(cache=True, inline="always")
def general_sky_inline(a, b, c, d, e, norm, cos_z, cos_chi):
    """L / Lz of the CIE general sky for a direction with cos Z = cos_z (clamped to the horizon) and cos χ = cos_chi;
    norm = 1 / (f(Zs)·φ(0))."""
    phi = 1.0
    if cos_z > 0.0:
        phi = 1.0 + a * math.exp(b / cos_z)
    cc = max(-1.0, min(1.0, cos_chi))  # a unit ray · the unit sun vector can round past ±1
    chi = math.acos(cc)
    f = 1.0 + c * (math.exp(d * chi) - math.exp(d * 0.5 * math.pi)) + e * cc * cc
    return f * phi * norm
