"""Shim et al. gamma-gradient exposure control (docs/controllers.md, Shim gamma-gradient).

One frame per decision: the current grey frame is gamma-remapped with each γ ∈ Γ, each remap is scored by Shim's
gradient information M (mapped Sobel gradient, `metrics.shim_gradient_information`), and exposure moves towards
the γ that maximised it.

Convention trap (docs/controllers.md): Mehta's 2018 code maps I → I^(1/γ) (γ > 1 brightens) while Zhang's Shim 2014
maps I → I^γ (γ < 1 brightens). Here each variant keeps its source's convention and `remap_gamma(..., convention)`
makes it explicit; `test_shim.py` checks that both brighten a dark scene.

variant "2018" (default; Mehta, aer_auto_exposure_gradient), convention I^(1/γ), Γ = {1/1.9, 1/1.5, 1/1.2, 1, 1.2, 1.5, 1.9}:
  fit a 5th-order polynomial M(γ), take its maximiser γ̂ in [min Γ, max Γ]; the best sample instead when the fit is
  not finite or the polynomial's maximum is below the best sampled M (as Mehta's code does);
  R = d·tan((2 − γ̂)·atan(1/d) − atan(1/d)) + 1, d = 0.1; EV ← (1 + α·K_p·(R − 1))·EV, EV = log2(N²/(t·2^(g/6))).
variant "2014" (Zhang's implementation), convention I^γ, Γ = {0.1, 0.5, 0.8, 1, 1.2, 1.5, 1.9}:
  γ̂ = best sample; t·gain ← t·gain·(1 + α·K_p·(1 − γ̂)).
α = `alpha_brighten` when the update brightens, `alpha_darken` when it darkens. Mehta's code uses 1 for both (our
default); Shim's 2014 paper darkens at half speed (alpha_darken 0.5, use it with variant "2014").
EV uses N = `f_number` (Mehta: 2.8, N² = 7.84); with the multiplicative EV update, N scales the step size.
The new exposure product is split exposure-first: exposure in [exposure_lower_us, exposure_upper_us] with gain 0;
only beyond the upper limit does gain take the rest (Mehta: gain += 6·ΔEV while clamped, else 0 — identical
when the exposure was already clamped; ours is exact when it reaches the limit within the step).
Processes every `process_every_n_frames`-th frame (Mehta: 2, so each decision sees a frame at the last command).
Deviation (ours): when M is flat over Γ (black or fully saturated frames carry no gradient), γ̂ is the most
brightening γ for a dark frame (mean < 127.5) and the most darkening one otherwise, instead of an arbitrary argmax.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import math

import numpy as np

from expoctl.camera.ranges import GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.controllers.base import Controller, Settings
from expoctl.controllers.registry import register_controller
from expoctl.controllers.metrics import luma_uint8, shim_gradient_information
from expoctl.config_reader import Section, read_config

GAMMAS = {"2018": [1 / 1.9, 1 / 1.5, 1 / 1.2, 1.0, 1.2, 1.5, 1.9], "2014": [0.1, 0.5, 0.8, 1.0, 1.2, 1.5, 1.9]}
CONVENTION = {"2018": "inverse", "2014": "direct"}  # inverse: I^(1/γ) (γ > 1 brightens); direct: I^γ

@dataclass(frozen=True)
class ShimConfig:
    """`controllers.shim`."""

    variant: str = "2018"
    lam: float = 1e3  # Shim's λ (paper value; Zhang's repo uses 10)
    delta: float = 0.06  # Shim's δ (paper value; Zhang's repo uses 0.11)
    k_p: float = 0.4  # Mehta header (0.25 in its local.yaml); Zhang's 2014 uses 0.2 — set per variant in config
    d: float = 0.1  # 2018 R-curve shape
    alpha_brighten: float = 1.0
    alpha_darken: float = 1.0
    f_number: float = 2.8  # N in EV = log2(N²/(t·2^(g/6))); the 2018 update scales EV multiplicatively, so N matters
    poly_order: int = 5
    process_every_n_frames: int = 2
    exposure_lower_us: float = 100.0  # Mehta clamps to [100 µs, min(1/fps, 32.754 ms)]
    exposure_upper_us: float = 30000.0
    gain_upper_db: float = GAIN_DB_MAX
    flat_tolerance: float = 1e-9  # M spread below which the metric is treated as flat

    def check(self, r: Section) -> None:
        """Bounds and the rules between keys (read_config runs it once every key has the right type)."""
        checks = [
            (self.variant in GAMMAS, "variant", "must be '2018' or '2014' (a string)"),
            (self.lam > 0, "lam", "must be > 0"),
            (0.0 <= self.delta < 1.0, "delta", "must be in [0, 1)"),
            (self.k_p > 0, "k_p", "must be > 0"),
            (0.0 < self.d <= 10.0, "d", "must be in (0, 10]"),
            (self.alpha_brighten > 0 and self.alpha_darken > 0, "alpha_darken", "alphas must be > 0"),
            (self.f_number >= 1.0, "f_number", "must be >= 1 (keeps EV positive)"),
            (1 <= self.poly_order <= 6, "poly_order", "must be in [1, 6] (7 gamma samples)"),
            (self.process_every_n_frames >= 1, "process_every_n_frames", "must be >= 1"),
            (75.0 <= self.exposure_lower_us < self.exposure_upper_us <= 30000.0, "exposure_upper_us", "need 75 <= exposure_lower_us < exposure_upper_us <= 30000"),
            (GAIN_DB_MIN <= self.gain_upper_db <= GAIN_DB_MAX, "gain_upper_db", "must be in [0, 30]"),
            (self.flat_tolerance >= 0, "flat_tolerance", "must be >= 0"),
        ]
        for ok, key, problem in checks:
            if not ok:
                r.problem(key, problem)


def remap_gamma(grey_uint8: np.ndarray, gamma: float, convention: str) -> np.ndarray:
    """Gamma-remap an 8-bit grey image to 0–255 float: I^(1/γ) ("inverse", Mehta) or I^γ ("direct", Zhang)."""
    expo = 1.0 / gamma if convention == "inverse" else gamma
    lut = 255.0 * (np.arange(256) / 255.0) ** expo
    return lut[grey_uint8]


def brightens(gamma: float, convention: str) -> bool:
    return gamma > 1.0 if convention == "inverse" else gamma < 1.0


@register_controller("shim", config=ShimConfig, label="Shim", colour="#8c564b", rank=30)
class ShimController(Controller):
    name = "shim"

    def __init__(self, config: ShimConfig | dict | None = None):
        """`config`: the typed config, or its section as a mapping (read and checked here)."""
        if not isinstance(config, ShimConfig):
            config = read_config(ShimConfig, config, "controllers.shim")
        p = self.config = config
        # EV = log2(N²/(t·2^(g/6))) must stay > 0 over the whole range (t·2^(g/6) ≤ 0.03 s·32 < 1) or the
        # multiplicative EV update reverses direction: N ≥ 1 guarantees it
        self.gammas = np.array(GAMMAS[p.variant])
        self.convention = CONVENTION[p.variant]
        self.reset(Settings(0.0, 5000.0))

    def reset(self, initial: Settings) -> None:
        self._command = initial.clamped()
        self._frame = 0

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        self._frame += 1
        if (self._frame - 1) % self.config.process_every_n_frames:
            return self._command
        grey = luma_uint8(image)
        gamma_hat = self.best_gamma(grey)
        self._command = self._step(gamma_hat, applied.clamped())
        return self._command

    # ------------------------------------------------------------------------------------------------ internals
    def scores(self, grey: np.ndarray) -> np.ndarray:
        p = self.config
        return np.array(
            [shim_gradient_information(remap_gamma(grey, g, self.convention), p.lam, p.delta) for g in self.gammas]
        )

    def best_gamma(self, grey: np.ndarray) -> float:
        m = self.scores(grey)
        if m.max() - m.min() <= self.config.flat_tolerance:
            want_brighter = float(grey.mean()) < 127.5
            most_brightening = self.gammas.max() if self.convention == "inverse" else self.gammas.min()
            most_darkening = self.gammas.min() if self.convention == "inverse" else self.gammas.max()
            return float(most_brightening if want_brighter else most_darkening)
        best_sample = float(self.gammas[int(np.argmax(m))])
        if self.config.variant == "2014":
            return best_sample
        with np.errstate(all="ignore"):
            try:
                coef = np.polyfit(self.gammas, m, self.config.poly_order)
            except (np.linalg.LinAlgError, ValueError):
                return best_sample
        grid = np.linspace(self.gammas.min(), self.gammas.max(), 721)
        fit = np.polyval(coef, grid)
        if not np.all(np.isfinite(fit)):
            return best_sample
        i = int(np.argmax(fit))
        return float(grid[i]) if fit[i] >= m.max() else best_sample

    def _step(self, gamma_hat: float, applied: Settings) -> Settings:
        p = self.config
        alpha = p.alpha_brighten if brightens(gamma_hat, self.convention) else p.alpha_darken
        ln_product = math.log(applied.exposure_us) + applied.gain_db / (20.0 / math.log(10.0))
        if p.variant == "2018":
            d = p.d
            r = d * math.tan((2.0 - gamma_hat) * math.atan(1.0 / d) - math.atan(1.0 / d)) + 1.0
            # EV with t in seconds and gain at 6 dB per stop (Mehta's 2^(g/6))
            ev = math.log2(p.f_number ** 2 / (applied.exposure_us * 1e-6 * 2.0 ** (applied.gain_db / 6.0)))
            ev_new = (1.0 + alpha * p.k_p * (r - 1.0)) * ev
            # product change in stops, gain counted at 6.02 dB/stop like every other controller here
            ln_product += (ev - ev_new) * math.log(2.0)
        else:
            factor = 1.0 + alpha * p.k_p * (1.0 - gamma_hat)
            ln_product += math.log(max(factor, 1e-3))
        return self._split(ln_product)

    def _split(self, ln_product: float) -> Settings:
        p = self.config
        t = float(np.clip(math.exp(ln_product), p.exposure_lower_us, p.exposure_upper_us))
        g = float(np.clip((ln_product - math.log(t)) * 20.0 / math.log(10.0), 0.0, p.gain_upper_db))
        return Settings(g, t).clamped()
