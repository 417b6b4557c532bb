"""Camera-model validation against real bracketed stacks: response recovery, merging, re-exposure, response fits.

The check (simulator spec, "Real multi-exposure data"): recover a real camera's response from a bracketed stack
(Debevec & Malik 1997, via OpenCV), merge the brackets to relative radiance, re-expose that radiance at a held-out
bracket's exposure time through OUR sensor (its linear EMVA-1288 chain: electrons, noise, full well, ADC) followed by
a response curve, and compare with the real frame (RMSE relative to 8-bit full scale).

Units. The recovered curve maps an 8-bit code z to a relative exposure X(z) = exp(g(z)) (OpenCV pins g(128) = 0 per
channel, so X = 1 is "mid-grey" in every channel); the merged radiance R is in X per second. The sensor's linear signal
is x = (DN − black) / (ADC max − black) ∈ [0, 1] (1 = ADC full scale). A re-exposure at time t sets x = κ·R·t, i.e.
electrons = c·R·t with c = κ·(electrons at ADC full scale); κ is fitted on the training brackets only.

Parametric response (our curve family; the pedestal is not a sensor config key yet): code/255 = offset + (1 − offset)·F(x), with F our
sRGB or power-law curve (`expoctl.camera.response`) and an output pedestal `offset` (real 8-bit images sit on a flare /
black floor of ~13–19 codes). Tying the gain to 1 − offset makes x = 1 (ADC full scale) map to code 255 and removes
the gain/exposure-scale degeneracy of a power law.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy.optimize import least_squares, minimize_scalar

from expoctl.camera.response import SATURATED_DN, apply_curve
from expoctl.camera.sensor import Sensor, SensorConfig
from expoctl.errors import InputError

FLOOR_DN = 20        # codes ≤ this are at the black/flare floor (the Memorial stack's plateau is ~13–19)


# ---------------------------------------------------------------- stack I/O and bookkeeping

def load_bracketed_stack(directory: str | Path, list_name: str = "exposure_times.txt"
                         ) -> tuple[list[np.ndarray], np.ndarray, list[str]]:
    """Read `<directory>/<list_name>` (lines "file seconds", # comments) → (uint8 RGB images, times_s, file names)."""
    directory = Path(directory)
    listing = directory / list_name
    if not listing.is_file():
        raise InputError(f"{listing}: exposure list not found")
    images, times, names = [], [], []
    for lineno, line in enumerate(listing.read_text().splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        try:
            name, t = parts[0], float(parts[1])
        except (IndexError, ValueError):
            raise InputError(f"{listing}:{lineno}: expected 'file seconds', got {line!r}") from None
        if not t > 0:
            raise InputError(f"{listing}:{lineno}: exposure time must be positive, got {t}")
        img = cv2.imread(str(directory / name), cv2.IMREAD_COLOR)
        if img is None:
            raise InputError(f"{listing}:{lineno}: cannot read image {directory / name}")
        if images and img.shape != images[0].shape:
            raise InputError(f"{directory / name}: shape {img.shape} differs from {images[0].shape}")
        images.append(np.ascontiguousarray(img[..., ::-1]))
        times.append(t)
        names.append(name)
    if len(images) < 3:
        raise InputError(f"{listing}: need at least 3 brackets, found {len(images)}")
    return images, np.asarray(times, np.float64), names


def valid_mask(real: np.ndarray, floor_dn: int = FLOOR_DN, saturated_dn: int = SATURATED_DN) -> np.ndarray:
    """Samples (pixel × channel) that are neither at the black floor nor saturated in the real frame."""
    return (real > floor_dn) & (real < saturated_dn)


def plateau_brackets(images: list[np.ndarray], min_valid_share: float = 0.05, floor_dn: int = FLOOR_DN,
                     saturated_dn: int = SATURATED_DN) -> list[int]:
    """Indices of brackets with fewer than `min_valid_share` of their samples between the floor and saturation.

    In the Memorial stack these are the darkest frames, whose signal no longer falls by half per stop but sits on
    the ~19-code flare/black floor: they carry almost no radiance information and would pull the recovered curve's
    toe towards a constant.
    """
    return [i for i, im in enumerate(images) if valid_mask(im, floor_dn, saturated_dn).mean() < min_valid_share]


def rmse_percent(predicted: np.ndarray, real: np.ndarray, mask: np.ndarray) -> float:
    """RMSE over the masked samples, in percent of 8-bit full scale (255)."""
    if not mask.any():
        raise ValueError("no samples to compare")
    d = predicted[mask].astype(np.float64) - real[mask].astype(np.float64)
    return float(100.0 * np.sqrt(np.mean(d * d)) / 255.0)


# ---------------------------------------------------------------- Debevec recovery and merge (OpenCV)

def recover_response(images: list[np.ndarray], times_s: np.ndarray, samples: int = 70,
                     smoothness: float = 10.0) -> np.ndarray:
    """Debevec–Malik inverse response: (256, 3) float64 relative exposure X(z) per code and channel (X(128) = 1)."""
    cal = cv2.createCalibrateDebevec(samples, smoothness, False)
    resp = cal.process([np.ascontiguousarray(im) for im in images], np.asarray(times_s, np.float32))
    return resp[:, 0, :].astype(np.float64)


def merge_radiance(images: list[np.ndarray], times_s: np.ndarray, response: np.ndarray, method: str = "masked",
                   floor_dn: int = FLOOR_DN, saturated_dn: int = SATURATED_DN) -> np.ndarray:
    """Weighted merge of the brackets to relative radiance (X per second), float32 HxWx3.

    method "opencv": cv2.createMergeDebevec (hat weights over 0…255, so floor codes keep a weight of ~1/8 of the
    maximum). method "masked": the same log-domain Debevec average, ln R = Σ w(z)(ln X(z) − ln t) / Σ w(z), but with
    a hat on (floor_dn, saturated_dn) that is zero at and beyond both ends. On a stack whose dark brackets sit on a
    flare floor, a floor code z at a short time t claims a radiance X(z)/t far above the truth; the OpenCV weights
    let those claims in, the masked ones do not. Samples with no usable bracket fall back to the OpenCV hat weights.
    """
    if method == "opencv":
        resp = np.asarray(response, np.float32).reshape(256, 1, 3)
        merge = cv2.createMergeDebevec()
        return merge.process([np.ascontiguousarray(im) for im in images], np.asarray(times_s, np.float32), resp)
    if method != "masked":
        raise ValueError(f"unknown merge method {method!r} (masked | opencv)")
    ln_x = np.log(np.maximum(np.asarray(response, np.float64), 1e-300))
    z = np.arange(256)
    w_masked = np.clip(np.minimum(z - floor_dn, saturated_dn - z), 0, None).astype(np.float64)
    w_hat = np.minimum(z + 1, 256 - z).astype(np.float64)
    shape = images[0].shape
    num, den = np.zeros(shape), np.zeros(shape)
    num_hat, den_hat = np.zeros(shape), np.zeros(shape)
    channels = np.arange(3)
    for im, t in zip(images, np.asarray(times_s, np.float64)):
        sample = ln_x[im, channels] - np.log(t)
        num += w_masked[im] * sample
        den += w_masked[im]
        num_hat += w_hat[im] * sample
        den_hat += w_hat[im]
    out = np.where(den > 0, num / np.where(den > 0, den, 1.0), num_hat / den_hat)
    return np.exp(out).astype(np.float32)


def isotonic_increasing(y: np.ndarray) -> np.ndarray:
    """Least-squares non-decreasing fit to a sequence (pool-adjacent-violators): a spike is averaged with its
    neighbours instead of being carried up the curve, as a running maximum would."""
    values, counts = [], []
    for v in np.asarray(y, np.float64):
        values.append(float(v))
        counts.append(1)
        while len(values) > 1 and values[-2] > values[-1]:
            n = counts[-2] + counts[-1]
            values[-2] = (values[-2] * counts[-2] + values[-1] * counts[-1]) / n
            counts[-2] = n
            values.pop()
            counts.pop()
    return np.repeat(values, counts)


def monotone_log_response(response: np.ndarray) -> np.ndarray:
    """ln X(z) made strictly increasing in z per channel (isotonic fit: the recovered curve wiggles at the ends, where
    few samples constrain it), so that its inverse x → code is a function."""
    g = np.log(np.maximum(np.asarray(response, np.float64), 1e-300))
    g = np.stack([isotonic_increasing(g[:, c]) for c in range(g.shape[1])], axis=1)
    return g + 1e-9 * np.arange(256)[:, None]


# ---------------------------------------------------------------- response curves as x → code

@dataclass(frozen=True)
class ParametricResponse:
    """code/255 = offset + (1 − offset)·F(x), F = our `curve` ('srgb' | 'gamma' with `gamma`)."""

    curve: str = "srgb"
    gamma: float = 2.2
    offset: float = 0.0

    def code(self, x_norm: np.ndarray) -> np.ndarray:
        """Linear signal (0 = black level, 1 = ADC full scale) → continuous code in [0, 255]."""
        y = self.offset + (1.0 - self.offset) * apply_curve(np.asarray(x_norm, np.float64), self.curve, self.gamma)
        return 255.0 * np.clip(y, 0.0, 1.0)


@dataclass(frozen=True)
class TabulatedResponse:
    """The recovered Debevec curve itself, as x → code: x = X / x_full_scale, code = g⁻¹(ln X) per channel."""

    log_response: np.ndarray   # (256, 3) strictly increasing ln X(z)
    x_full_scale: float        # relative exposure X that maps to x = 1 (ADC full scale)

    def code(self, x_norm: np.ndarray) -> np.ndarray:
        """x (..., 3) per channel → continuous code (..., 3); below/above the curve's range it clamps to 0/255."""
        x = np.asarray(x_norm, np.float64)
        if x.ndim == 0 or x.shape[-1] != 3:
            raise ValueError(f"x must have a last axis of 3 channels, got shape {x.shape}")
        ln_x = np.log(np.maximum(x * self.x_full_scale, 1e-300))
        out = np.empty(x.shape, np.float64)
        for c in range(3):
            out[..., c] = np.interp(ln_x[..., c], self.log_response[:, c], np.arange(256.0))
        return out


@dataclass(frozen=True)
class ChannelResponse:
    """One parametric curve per colour channel, each after its own digital gain (white balance):
    code_c = responses[c].code(gains[c]·x_c). Film and many camera pipelines have per-channel tone curves. The
    sensor's 8-bit stage has the same model as config keys (`sensor_keys`, `expoctl.camera.response`).
    """

    responses: tuple[ParametricResponse, ParametricResponse, ParametricResponse]
    gains: tuple[float, float, float]

    def code(self, x_norm: np.ndarray) -> np.ndarray:
        x = np.asarray(x_norm, np.float64)
        if x.ndim == 0 or x.shape[-1] != 3:
            raise ValueError(f"x must have a last axis of 3 channels, got shape {x.shape}")
        out = np.empty(x.shape, np.float64)
        for c in range(3):
            out[..., c] = self.responses[c].code(self.gains[c] * x[..., c])
        return out

    def sensor_keys(self) -> dict:
        """The sensor config keys (conf/sensor) that make `Sensor` deliver exactly this response: response_curve,
        response_gamma_rgb, response_pedestal_rgb (the offsets) and white_balance_rgb (the gains)."""
        curves = {r.curve for r in self.responses}
        if len(curves) != 1:
            raise ValueError(f"the sensor has one curve family for all channels, got {sorted(curves)}")
        return {"response_curve": curves.pop(), "response_gamma_rgb": [float(r.gamma) for r in self.responses],
                "response_pedestal_rgb": [float(r.offset) for r in self.responses],
                "white_balance_rgb": [float(g) for g in self.gains]}


def code_histogram(images: list[np.ndarray]) -> np.ndarray:
    """(256, 3) counts of each code per channel over the images: weights for `fit_parametric_response`."""
    return np.stack([sum(np.bincount(im[..., c].ravel(), minlength=256) for im in images) for c in range(3)], axis=1)


def fit_parametric_response(response: np.ndarray, curve: str = "srgb", fit_gamma: bool = False,
                            fit_offset: bool = True, code_weights: np.ndarray | None = None,
                            code_range: tuple[int, int] = (FLOOR_DN + 1, SATURATED_DN - 1),
                            per_channel: bool = False) -> tuple[ParametricResponse | ChannelResponse, float, dict]:
    """Least-squares fit of a `ParametricResponse` to a recovered curve, in code space (what the RMSE measures).

    Each code z in `code_range` and channel gives a point (X(z), z); the model is z ≈ code(X / x_full_scale) with one
    curve shared by the channels (our sensor has one response). `code_weights` (256, 3), e.g. `code_histogram` of
    the training brackets, weights each point by how many pixels carry that code, so the fit minimises the expected
    squared code error of an image rather than of the (sparsely sampled, noisy) curve ends. Returns (response,
    x_full_scale, info) with the fit's (weighted) RMSE in codes.

    per_channel=True fits each channel on its own (its own scale, gamma and pedestal) and returns a `ChannelResponse`:
    x_full_scale is the largest channel scale and each channel's gain is x_full_scale / its own scale (≥ 1), so no
    channel needs a linear signal above ADC full scale to reach code 255. The per-channel scales themselves carry no
    information (the recovered curve pins X(128) = 1 in each channel, an arbitrary unit per channel); the per-channel
    gammas and pedestals are the extra model.
    """
    response = np.asarray(response, np.float64)
    if response.shape != (256, 3):
        raise ValueError(f"response must be (256, 3), got {response.shape}")
    if per_channel:
        w = np.ones((256, 3)) if code_weights is None else np.asarray(code_weights, np.float64)
        fits = [fit_parametric_response(np.repeat(response[:, c:c + 1], 3, axis=1), curve, fit_gamma, fit_offset,
                                        np.repeat(w[:, c:c + 1], 3, axis=1), code_range) for c in range(3)]
        scales = np.array([f[1] for f in fits])
        x_fs = float(scales.max())
        fitted = ChannelResponse(tuple(f[0] for f in fits), tuple(float(x_fs / s) for s in scales))
        per = np.array([f[2]["fit_rmse_codes"] for f in fits])
        share = w[code_range[0]:code_range[1] + 1].sum(axis=0)
        info = {"fit_rmse_codes": float(np.sqrt(np.sum(per ** 2 * share) / share.sum())), "codes": list(code_range),
                "gamma_rgb": [f[0].gamma for f in fits], "offset_codes_rgb": [255 * f[0].offset for f in fits],
                "gain_rgb": list(fitted.gains)}
        return fitted, x_fs, info
    lo, hi = code_range
    codes = np.arange(lo, hi + 1, dtype=np.float64)
    ln_x = np.log(np.maximum(response[lo:hi + 1], 1e-300)).ravel()  # (n·3,)
    target = np.repeat(codes[:, None], 3, axis=1).ravel()
    weights = np.ones_like(target) if code_weights is None else np.asarray(code_weights, np.float64)[lo:hi + 1].ravel()
    if weights.shape != target.shape or not np.all(weights >= 0) or weights.sum() <= 0:
        raise ValueError("code_weights must be a non-negative (256, 3) array with some weight in the code range")
    sqrt_w = np.sqrt(weights / weights.sum())

    def unpack(p):
        gamma = p[1] if fit_gamma else 2.2
        offset = p[-1] if fit_offset else 0.0
        return p[0], gamma, offset

    def residual(p):
        ln_scale, gamma, offset = unpack(p)
        return sqrt_w * (ParametricResponse(curve, gamma, offset).code(np.exp(ln_x - ln_scale)) - target)

    p0 = [float(np.max(ln_x)) + 0.5] + ([2.2] if fit_gamma else []) + ([0.05] if fit_offset else [])
    lower = [-np.inf] + ([0.3] if fit_gamma else []) + ([-0.5] if fit_offset else [])
    upper = [np.inf] + ([6.0] if fit_gamma else []) + ([0.5] if fit_offset else [])
    sol = least_squares(residual, p0, bounds=(lower, upper), x_scale="jac")
    ln_scale, gamma, offset = unpack(sol.x)
    fitted = ParametricResponse(curve, float(gamma), float(offset))
    info = {"fit_rmse_codes": float(np.sqrt(np.sum(sol.fun ** 2))), "codes": [lo, hi]}
    return fitted, float(np.exp(ln_scale)), info


# ---------------------------------------------------------------- re-exposure through our sensor

def adc_code_lut(cfg: SensorConfig, response) -> np.ndarray:
    """(ADC codes, 3) uint8 table: black-level subtraction, normalisation, the response's `code`, rounded — the same
    chain as `Sensor.raw_to_8bit`, for any response with a `code(x)` method."""
    dn = np.arange(cfg.adc_max_dn + 1, dtype=np.float64)
    x = (dn - cfg.black_level_dn) / (cfg.adc_max_dn - cfg.black_level_dn)
    codes = response.code(np.repeat(x[:, None], 3, axis=1))
    return np.clip(np.rint(codes), 0, 255).astype(np.uint8)


def apply_lut(raw_dn: np.ndarray, lut: np.ndarray) -> np.ndarray:
    """Per-channel lookup of integer raw DN (H, W, 3) in an (n_codes, 3) table."""
    idx = raw_dn.astype(np.int64)
    out = np.empty(idx.shape, np.uint8)
    for c in range(3):
        out[..., c] = lut[idx[..., c], c]
    return out


def noise_free_codes(radiance: np.ndarray, time_s: float, kappa: float, cfg: SensorConfig,
                     lut: np.ndarray) -> np.ndarray:
    """The sensor chain without noise or fixed-pattern maps: x = κ·R·t → DN (rounded, clipped) → code."""
    span = cfg.adc_max_dn - cfg.black_level_dn
    dn = np.rint(np.asarray(radiance, np.float64) * (kappa * time_s * span) + cfg.black_level_dn)
    return apply_lut(np.clip(dn, 0, cfg.adc_max_dn), lut)


def fit_exposure_scale(radiance: np.ndarray, images: list[np.ndarray], times_s: np.ndarray, cfg: SensorConfig,
                       lut: np.ndarray, kappa0: float, stride: int = 4) -> float:
    """κ (linear signal per unit radiance·second) minimising the code RMSE of noise-free re-exposures of the given
    (training) brackets over their valid samples; searched within ±2 stops of `kappa0` on a pixel grid of `stride`."""
    r = radiance[::stride, ::stride]
    reals = [im[::stride, ::stride] for im in images]
    masks = [valid_mask(im) for im in reals]

    def cost(ln_k):
        err, n = 0.0, 0
        for im, m, t in zip(reals, masks, times_s):
            d = noise_free_codes(r, float(t), float(np.exp(ln_k)), cfg, lut)[m].astype(np.float64) - im[m]
            err += float(np.dot(d, d))
            n += d.size
        return err / max(n, 1)

    ln0 = np.log(kappa0)
    res = minimize_scalar(cost, bounds=(ln0 - 2 * np.log(2), ln0 + 2 * np.log(2)), method="bounded",
                          options={"xatol": 1e-4})
    return float(np.exp(res.x))


def reexpose(sensor: Sensor, radiance: np.ndarray, time_s: float, kappa: float, lut: np.ndarray,
             rng: np.random.Generator, exposure_us: float = 10000.0, gain_db: float = 0.0) -> np.ndarray:
    """Re-expose relative radiance at `time_s` through the sensor's noisy linear chain, then the response `lut`.

    The real brackets (1/1024–32 s) lie outside the simulator's exposure range, so the sensor runs at `exposure_us`
    and the scene luminance is scaled to give the same mean electrons: electrons = c·R·t with c = κ·e⁻(full scale).
    """
    cfg = sensor.cfg
    e_full_scale = (cfg.adc_max_dn - cfg.black_level_dn) / (cfg.k0_dn_per_e * 10.0 ** (gain_db / 20.0))
    electrons_per_unit = kappa * time_s * e_full_scale
    per_cd_m2 = cfg.photons_per_cd_m2_s() * 1e-6 * exposure_us * cfg.quantum_efficiency
    luminance = (np.asarray(radiance, np.float32) * np.float32(electrons_per_unit / per_cd_m2))
    raw = sensor.capture_raw(luminance, exposure_us, gain_db, rng)
    return apply_lut(raw, lut)


# ---------------------------------------------------------------- residual diagnostics

def estimate_noise_sigma(image: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Per-channel temporal-noise σ of one frame in codes, from the frame alone (Immerkær 1996): the 3×3 kernel
    [[1, −2, 1], [−2, 4, −2], [1, −2, 1]] cancels any locally planar signal and multiplies white noise's variance by
    36, so K∗I has σ_K = 6σ. Immerkær averages |K∗I| (σ = √(π/2)·mean|K∗I| / 6); here the median is used, for which
    median|N(0, σ_K)| = 0.6745·σ_K, so σ = median|K∗I| / (6 · 0.6745): edges are outliers and do not move a median.
    Used to split a real-vs-model RMSE into the real frame's own noise and the rest. Returns (channels,) float64."""
    img = np.asarray(image, np.float64)
    if img.ndim == 2:
        img = img[..., None]
    m = np.ones(img.shape, bool) if mask is None else np.asarray(mask, bool).reshape(img.shape)
    m = m.copy()
    m[:1], m[-1:], m[:, :1], m[:, -1:] = False, False, False, False  # the kernel needs all 8 neighbours
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float64)
    out = []
    for c in range(img.shape[2]):
        response = cv2.filter2D(img[..., c], cv2.CV_64F, kernel, borderType=cv2.BORDER_REPLICATE)
        sel = m[..., c]
        out.append(np.median(np.abs(response[sel])) / (6.0 * 0.6744897501960817) if sel.any() else np.nan)
    return np.asarray(out)


def rmse_after_code_bias(predicted: np.ndarray, real: np.ndarray, mask: np.ndarray) -> float:
    """RMSE (% of 255) left after removing, per channel, the mean error at each real code: what a perfect per-code
    correction of the tone curve could remove is the difference to `rmse_percent`. Diagnostic: it uses the compared
    frame itself."""
    pred = np.asarray(predicted, np.float64)
    real_i = np.asarray(real)
    resid = []
    for c in range(real_i.shape[-1]):
        sel = mask[..., c]
        z = real_i[..., c][sel].astype(np.int64)
        d = pred[..., c][sel] - z
        bias = np.bincount(z, d, 256) / np.maximum(np.bincount(z, None, 256), 1)
        resid.append(d - bias[z])
    r = np.concatenate(resid)
    if r.size == 0:
        raise ValueError("no samples to compare")
    return float(100.0 * np.sqrt(np.mean(r * r)) / 255.0)


def local_shift_fit(predicted: np.ndarray, real: np.ndarray, mask: np.ndarray, tile: int = 32,
                    max_shift_px: float = 1.5, min_samples: int = 50, iterations: int = 4
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Diagnostic registration bound: per `tile`×`tile` block, the sub-pixel translation s (`iterations`
    Lucas–Kanade steps on the shifted prediction's Sobel gradients, least squares over the block's masked samples,
    clipped to ±max_shift_px)
    that best maps the prediction onto the real frame, real(x) ≈ pred(x + s); returns (the prediction resampled
    with each block's shift (bilinear, float64), shifts (tiles_y, tiles_x, 2) as (dx, dy), NaN where a block has
    fewer than `min_samples`). It uses the compared frame, so it is not a validation number: the drop in RMSE
    bounds how much of the residual is local misregistration between the real frames (any local geometric
    mismatch up to ~1 px, plus whatever photometric error happens to correlate with the gradient)."""
    pred = np.asarray(predicted, np.float32)
    real_f = np.asarray(real, np.float32)
    if pred.shape != real_f.shape or pred.ndim != 3:
        raise ValueError(f"predicted and real must be HxWxC of the same shape, got {pred.shape}, {real_f.shape}")
    h, w, ch = pred.shape
    gx = np.stack([cv2.Sobel(pred[..., c], cv2.CV_32F, 1, 0, borderType=cv2.BORDER_REPLICATE) / 8
                   for c in range(ch)], -1)
    gy = np.stack([cv2.Sobel(pred[..., c], cv2.CV_32F, 0, 1, borderType=cv2.BORDER_REPLICATE) / 8
                   for c in range(ch)], -1)
    out = pred.astype(np.float64).copy()
    ny, nx = -(-h // tile), -(-w // tile)
    shifts = np.full((ny, nx, 2), np.nan)
    for ty in range(ny):
        for tx in range(nx):
            # Edge blocks end at the image border when `tile` does not divide it (the pixel grid must match the
            # mask's clipped block, so the slices are clipped here rather than left to numpy indexing).
            sl = (slice(ty * tile, min((ty + 1) * tile, h)), slice(tx * tile, min((tx + 1) * tile, w)))
            mm = np.asarray(mask, bool)[sl]
            if mm.sum() < min_samples:
                continue
            ys, xs = np.mgrid[sl].astype(np.float32)
            s = np.zeros(2)
            for _ in range(max(1, iterations)):
                warp = [xs + np.float32(s[0]), ys + np.float32(s[1])]
                moved = cv2.remap(pred, *warp, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).reshape(mm.shape)
                a = np.stack([cv2.remap(gx, *warp, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                              .reshape(mm.shape)[mm],
                              cv2.remap(gy, *warp, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
                              .reshape(mm.shape)[mm]], 1).astype(np.float64)
                b = (real_f[sl] - moved)[mm].astype(np.float64)
                s = np.clip(s + np.linalg.lstsq(a, b, rcond=None)[0], -max_shift_px, max_shift_px)
            shifts[ty, tx] = s
            out[sl] = cv2.remap(pred, xs + np.float32(s[0]), ys + np.float32(s[1]), cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE).reshape(mm.shape)
    return out, shifts
