"""EMVA-1288 linear camera model (Sony IMX265-class global-shutter CMOS, as in the FLIR Blackfly S BFS-U3-31S4C).

Scene luminance L (cd/m², per RGB channel) → image-plane illuminance E = π·L·T/(4·N²) (lux) → mean photons per
pixel μp = E·A·t / (h·c/λ · 683 lm/W) → electrons ~ Poisson(η·μp·(1 + PRNU)) + DSNU → charge clipped at the full
well → + read noise → DN = K(g)·e⁻ + black level, with K(g) = K₀·10^(g/20) → quantised and clipped to the ADC range.

Gain multiplies *after* the charge is collected and *before* the ADC clips, so it amplifies shot and read noise with
the signal and the saturation level in electrons falls as 1/gain: gain and exposure are not interchangeable
(exposure adds motion blur, gain adds noise and loses range). Check of the constants: on a 3.45 µm pixel at 555 nm,
1 lux·s gives ≈ 48.7k photons.

Shot noise: exact Poisson draws where the mean is below `poisson_exact_below` electrons (default 10), a Gaussian with
the same mean and variance above it (mean and variance exact; only the skewness 1/√μ ≤ 0.32 is lost), which is several
times faster than Poisson sampling of a whole frame.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numba
import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, GAIN_DB_MAX, GAIN_DB_MIN, SENSOR_EXPOSURE_US_MIN
from expoctl.camera.response import Response, response_from_config
from expoctl.config_reader import Problems, Section
from expoctl.errors import ConfigError, InputError

PLANCK_J_S = 6.62607015e-34
LIGHT_SPEED_M_S = 2.99792458e8
LUMENS_PER_WATT_555NM = 683.0


@dataclass(frozen=True)
class SensorConfig:
    quantum_efficiency: float = 0.6      # η at 555 nm
    full_well_e: float = 10500.0         # saturation capacity, electrons
    read_noise_e: float = 2.8            # temporal dark noise σ_d, electrons (≈ 71 dB single-frame range)
    prnu: float = 0.005                  # photo-response non-uniformity (σ of the gain map, fraction)
    dsnu_e: float = 1.0                  # dark-signal non-uniformity (σ of the offset map, electrons)
    adc_bits: int = 12
    system_gain_dn_per_e: float | None = None  # K at 0 dB; None = (2^bits − 1) / full well (full well fills the ADC)
    black_level_fraction: float = 0.015  # black level offset as a fraction of the ADC range
    f_number: float = 2.0
    lens_transmission: float = 0.9
    pixel_pitch_um: float = 3.45
    wavelength_nm: float = 555.0
    response_curve: str = "srgb"         # srgb | gamma | linear (expoctl.camera.response)
    response_gamma: float = 2.2          # only for response_curve: gamma
    response_gamma_rgb: tuple[float, float, float] | None = None  # per-channel gammas (R, G, B); None = response_gamma
    response_pedestal_rgb: tuple[float, float, float] = (0.0, 0.0, 0.0)  # output pedestal, units of the 8-bit range
    white_balance_rgb: tuple[float, float, float] = (1.0, 1.0, 1.0)      # digital gain per channel before the curve
    poisson_exact_below: float = 10.0    # electrons; Gaussian shot-noise approximation above

    _RGB = ("response_gamma_rgb", "response_pedestal_rgb", "white_balance_rgb")

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "sensor", problems: Problems | None = None) -> "SensorConfig":
        r = Section(d, key, problems)
        positive, non_negative = dict(above=0.0), dict(min=0.0)

        def rgb(name):  # YAML gives lists; the frozen config holds tuples (hashable)
            v = r.value(name, getattr(cls, name))
            return tuple(v) if isinstance(v, list) else v

        cfg = cls(
            quantum_efficiency=r.number("quantum_efficiency", cls.quantum_efficiency, above=0.0, max=1.0),
            full_well_e=r.number("full_well_e", cls.full_well_e, **positive),
            read_noise_e=r.number("read_noise_e", cls.read_noise_e, **non_negative),
            prnu=r.number("prnu", cls.prnu, min=0.0, below=0.5),
            dsnu_e=r.number("dsnu_e", cls.dsnu_e, **non_negative),
            adc_bits=r.integer("adc_bits", cls.adc_bits, min=8, max=16),
            system_gain_dn_per_e=r.number("system_gain_dn_per_e", cls.system_gain_dn_per_e, nullable=True,
                                          **positive),
            black_level_fraction=r.number("black_level_fraction", cls.black_level_fraction, min=0.0, below=0.5),
            f_number=r.number("f_number", cls.f_number, **positive),
            lens_transmission=r.number("lens_transmission", cls.lens_transmission, above=0.0, max=1.0),
            pixel_pitch_um=r.number("pixel_pitch_um", cls.pixel_pitch_um, **positive),
            wavelength_nm=r.number("wavelength_nm", cls.wavelength_nm, **positive),
            # the response keys' bounds are response_from_config's (shared with AG+AE's model), checked below
            response_curve=r.value("response_curve", cls.response_curve),
            response_gamma=r.value("response_gamma", cls.response_gamma),
            response_gamma_rgb=rgb("response_gamma_rgb"),
            response_pedestal_rgb=rgb("response_pedestal_rgb"),
            white_balance_rgb=rgb("white_balance_rgb"),
            poisson_exact_below=r.number("poisson_exact_below", cls.poisson_exact_below, **non_negative),
        )
        r.problems.collect(response_from_config, cfg.to_dict(), key)
        r.done()
        return cfg

    def validate(self, key: str = "sensor") -> None:
        """The same checks as a config read (one definition of the bounds: `from_dict`)."""
        type(self).from_dict(self.to_dict(), key)

    @property
    def adc_max_dn(self) -> int:
        return (1 << self.adc_bits) - 1

    @property
    def k0_dn_per_e(self) -> float:
        return self.system_gain_dn_per_e if self.system_gain_dn_per_e is not None else self.adc_max_dn / self.full_well_e

    @property
    def black_level_dn(self) -> float:
        return self.black_level_fraction * self.adc_max_dn

    def photons_per_cd_m2_s(self) -> float:
        """Mean photons per pixel per second for a scene luminance of 1 cd/m² (through the lens)."""
        illuminance_lux = math.pi * self.lens_transmission / (4.0 * self.f_number ** 2)
        area_m2 = (self.pixel_pitch_um * 1e-6) ** 2
        photon_energy_j = PLANCK_J_S * LIGHT_SPEED_M_S / (self.wavelength_nm * 1e-9)
        return illuminance_lux * area_m2 / (LUMENS_PER_WATT_555NM * photon_energy_j)

    def response(self) -> Response:
        return response_from_config(self.to_dict(), "sensor")

    def to_dict(self) -> dict:
        """Plain types (the per-channel tuples as lists), as sequence.yaml records the sensor."""
        d = dataclasses.asdict(self)
        for k in self._RGB:
            if d[k] is not None:
                d[k] = list(d[k])
        return d

    def randomised(self, rng: np.random.Generator, amplitude: float) -> "SensorConfig":
        """A unit-to-unit variation: η, full well, read noise, PRNU, DSNU and black level each × (1 ± U[0, amplitude])."""
        if not 0 <= amplitude < 0.5:
            raise ConfigError("sensor randomisation amplitude", f"must be in [0, 0.5), got {amplitude}")

        def jitter(v: float) -> float:
            return float(v * (1.0 + rng.uniform(-amplitude, amplitude)))

        return dataclasses.replace(
            self,
            quantum_efficiency=min(1.0, jitter(self.quantum_efficiency)),
            full_well_e=jitter(self.full_well_e),
            read_noise_e=jitter(self.read_noise_e),
            prnu=jitter(self.prnu),
            dsnu_e=jitter(self.dsnu_e),
            black_level_fraction=jitter(self.black_level_fraction),
        )


class Sensor:
    """One camera unit: a config plus its own fixed-pattern noise (PRNU and DSNU maps drawn from `seed`)."""

    def __init__(self, cfg: SensorConfig, height: int, width: int, seed: int = 0):
        cfg.validate()
        self.cfg = cfg
        self.height, self.width = int(height), int(width)
        fpn = np.random.default_rng(np.random.SeedSequence([int(seed), 0xF9]))
        shape = (self.height, self.width, 3)
        self._gain_map = (1.0 + cfg.prnu * fpn.standard_normal(shape)).astype(np.float32)
        self._dark_map = (cfg.dsnu_e * fpn.standard_normal(shape)).astype(np.float32)
        self._photons_per_cd_m2_us = np.float32(cfg.photons_per_cd_m2_s() * 1e-6)
        self.response = cfg.response()
        codes = np.arange(cfg.adc_max_dn + 1, dtype=np.float64)
        linear = (codes - cfg.black_level_dn) / (cfg.adc_max_dn - cfg.black_level_dn)
        # (ADC codes, 3): one column per colour channel (equal columns for a channel-uniform response)
        self._dn_to_8bit = np.ascontiguousarray(self.response.linear_to_8bit(np.repeat(linear[:, None], 3, axis=1)))
        self._noise_memory: dict[tuple, tuple[np.ndarray, dict]] | None = None
        self._noise_memory_size = 0
        self.noise_draws = 0  # per-pixel normal fields drawn (not served from the memory)

    def remember_noise(self, frames: int = 4) -> "Sensor":
        """Reuse each frame's per-pixel normal field: a generator that starts from a state seen in the last `frames`
        captures gets the field drawn then, and is left in the state drawing it left (so its later draws, the exact
        Poisson uniforms, are its own). Exact: a generator's draws are a function of its state. In closed-loop
        evaluation every controller and every oracle candidate captures frame t from the same fresh generator
        (`sensor_rng(seed, camera, t)`), so the field is drawn once per frame instead of once per capture."""
        self._noise_memory, self._noise_memory_size = {}, int(frames)
        return self

    def _normal_field(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        if self._noise_memory is None:
            self.noise_draws += 1
            return rng.standard_normal(shape, dtype=np.float32)
        state = rng.bit_generator.state
        key = (repr(state), shape)
        hit = self._noise_memory.get(key)
        if hit is not None:
            z, after = hit
            rng.bit_generator.state = after
            return z
        self.noise_draws += 1
        z = rng.standard_normal(shape, dtype=np.float32)
        if len(self._noise_memory) >= self._noise_memory_size:
            del self._noise_memory[next(iter(self._noise_memory))]  # the oldest: frames arrive in order
        self._noise_memory[key] = (z, rng.bit_generator.state)
        return z

    def mean_electrons(self, luminance_cd_m2: np.ndarray, exposure_us: float) -> np.ndarray:
        """Expected collected electrons per pixel (before shot noise and clipping)."""
        lum = np.asarray(luminance_cd_m2, dtype=np.float32)
        mu = lum * (self._photons_per_cd_m2_us * np.float32(exposure_us * self.cfg.quantum_efficiency))
        mu *= self._gain_map
        mu += self._dark_map
        np.maximum(mu, 0.0, out=mu)
        return mu

    def capture_raw(self, luminance_cd_m2: np.ndarray, exposure_us: float, gain_db: float,
                    rng: np.random.Generator) -> np.ndarray:
        """Linear raw frame in DN (float32, quantised, black level included, clipped to the ADC range)."""
        args = self._kernel_args(luminance_cd_m2, exposure_us, gain_db, rng)
        return _raw_kernel(*args)

    def _kernel_args(self, luminance_cd_m2, exposure_us, gain_db, rng):
        """Validated inputs and this frame's random draws for the compiled kernels.

        Draw order (fixed, so `capture` and `capture_raw` see the same noise for the same generator): one standard
        normal per pixel, then one uniform per exact-Poisson pixel (its Poisson draw; the normal is its read noise).
        """
        self._check(luminance_cd_m2, exposure_us, gain_db)
        cfg = self.cfg
        lum = np.ascontiguousarray(luminance_cd_m2, dtype=np.float32)
        scale = np.float32(float(self._photons_per_cd_m2_us) * exposure_us * cfg.quantum_efficiency)
        z = self._normal_field(rng, lum.shape)  # read-only in the kernels, so a remembered field is safe
        n_small = _count_small(lum, self._gain_map, self._dark_map, scale, np.float32(cfg.poisson_exact_below))
        z_small = rng.random(max(n_small, 1), dtype=np.float32)
        k = np.float32(cfg.k0_dn_per_e * 10.0 ** (gain_db / 20.0))
        return (lum, self._gain_map, self._dark_map, z, z_small, scale, np.float32(cfg.poisson_exact_below),
                np.float32(cfg.read_noise_e), np.float32(cfg.full_well_e), k, np.float32(cfg.black_level_dn),
                np.float32(cfg.adc_max_dn))

    def raw_to_8bit(self, raw_dn: np.ndarray) -> np.ndarray:
        """Black-level subtraction, normalisation to the usable ADC range and the response curve → uint8 RGB.

        Raw values are integers in [0, ADC max], so the whole chain is one lookup table over the ADC codes, one
        column per channel (raw_dn: (..., 3)).
        """
        if raw_dn.ndim == 0 or raw_dn.shape[-1] != 3:
            raise ValueError(f"raw_dn must have a last axis of 3 channels, got shape {raw_dn.shape}")
        return np.take_along_axis(self._dn_to_8bit, raw_dn.astype(np.int32).reshape(-1, 3), axis=0).reshape(raw_dn.shape)

    def capture(self, luminance_cd_m2: np.ndarray, exposure_us: float, gain_db: float,
                rng: np.random.Generator) -> np.ndarray:
        """The 8-bit RGB image the camera delivers for this scene and these settings.

        Same model and same random draws as `raw_to_8bit(capture_raw(...))` (a test checks they agree exactly), fused
        into one compiled pass over the pixels.
        """
        return _capture_kernel(*self._kernel_args(luminance_cd_m2, exposure_us, gain_db, rng), self._dn_to_8bit)

    def saturation_luminance_cd_m2(self, exposure_us: float, gain_db: float) -> float:
        """Scene luminance at which a pixel (without PRNU) reaches the first of full well or ADC full scale."""
        cfg = self.cfg
        k = cfg.k0_dn_per_e * 10.0 ** (gain_db / 20.0)
        e_sat = min(cfg.full_well_e, (cfg.adc_max_dn - cfg.black_level_dn) / k)
        return e_sat / (float(self._photons_per_cd_m2_us) * exposure_us * cfg.quantum_efficiency)

    def _check(self, luminance: np.ndarray, exposure_us: float, gain_db: float) -> None:
        if not (_finite_number(exposure_us) and SENSOR_EXPOSURE_US_MIN <= exposure_us <= EXPOSURE_US_MAX):
            raise InputError(f"exposure_us {exposure_us!r} outside {SENSOR_EXPOSURE_US_MIN:g}–{EXPOSURE_US_MAX:g} µs")
        if not (_finite_number(gain_db) and GAIN_DB_MIN <= gain_db <= GAIN_DB_MAX):
            raise InputError(f"gain_db {gain_db!r} outside {GAIN_DB_MIN:g}–{GAIN_DB_MAX:g} dB")
        if luminance.shape != (self.height, self.width, 3):
            raise ValueError(f"luminance has shape {luminance.shape}, sensor is {(self.height, self.width, 3)}")
        # NaN would index the DN→8-bit table out of range in the compiled kernel; min() propagates NaN (one cheap
        # pass). +inf is allowed (it saturates); small negatives from resampling are clamped to zero electrons.
        low = float(np.min(luminance))
        if math.isnan(low) or low == -math.inf:
            raise InputError(f"luminance_cd_m2 contains {'NaN' if math.isnan(low) else '-inf'} values")


@numba.njit(cache=True, inline="always")
def _pixel_dn(lum, gain, dark, z, z_small, j, scale, exact_below, read_noise, full_well, k, black, adc_max):
    """One pixel: mean electrons → shot + read noise → full-well clip → DN. Returns (dn, next index into z_small).

    Mean below `exact_below`: exact Poisson by inverse transform of the uniform z_small[j], read noise from z.
    Above: a Gaussian with the Poisson mean and variance plus the read noise variance (mean and variance exact; only
    the skewness 1/√μ ≤ 0.32 is lost).
    """
    mu = max(lum * scale * gain + dark, np.float32(0.0))
    if mu < exact_below:
        u = z_small[j]
        n = 0
        p = math.exp(-mu)
        c = p
        while u > c and n < 200:
            n += 1
            p *= mu / n
            c += p
        e = np.float32(n) + read_noise * z
        j += 1
    else:
        e = mu + np.float32(math.sqrt(mu + read_noise * read_noise)) * z
    e = min(e, full_well)
    dn = np.float32(np.rint(e * k + black))
    return min(max(dn, np.float32(0.0)), adc_max), j


@numba.njit(cache=True)
def _count_small(lum, gain_map, dark_map, scale, exact_below):
    fl, fg, fd = lum.ravel(), gain_map.ravel(), dark_map.ravel()
    n = 0
    for i in range(fl.size):
        if max(fl[i] * scale * fg[i] + fd[i], np.float32(0.0)) < exact_below:
            n += 1
    return n


@numba.njit(cache=True)
def _raw_kernel(lum, gain_map, dark_map, z, z_small, scale, exact_below, read_noise, full_well, k, black, adc_max):
    out = np.empty(lum.shape, np.float32)
    fl, fg, fd, fz, fo = lum.ravel(), gain_map.ravel(), dark_map.ravel(), z.ravel(), out.ravel()
    j = 0
    for i in range(fl.size):
        fo[i], j = _pixel_dn(fl[i], fg[i], fd[i], fz[i], z_small, j, scale, exact_below, read_noise, full_well, k,
                             black, adc_max)
    return out


@numba.njit(cache=True)
def _capture_kernel(lum, gain_map, dark_map, z, z_small, scale, exact_below, read_noise, full_well, k, black,
                    adc_max, lut):
    out = np.empty(lum.shape, np.uint8)
    fl, fg, fd, fz, fo = lum.ravel(), gain_map.ravel(), dark_map.ravel(), z.ravel(), out.ravel()
    j = 0
    n_pixels = fl.size // 3
    for p in range(n_pixels):  # C-order (H, W, 3): element 3·p + c is channel c of pixel p
        for c in range(3):
            i = 3 * p + c
            dn, j = _pixel_dn(fl[i], fg[i], fd[i], fz[i], z_small, j, scale, exact_below, read_noise, full_well, k,
                              black, adc_max)
            fo[i] = lut[np.int32(dn), c]
    return out


def _finite_number(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)
