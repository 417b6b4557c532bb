"""Mean-intensity proportional auto-exposure (Zhang et al.'s kMeanIntensity rule, docs/controllers.md, Mean intensity):
t ← t + k·t·(target/mean − 1) with k = 0.2 and target 127.5, i.e. the exposure product is multiplied by
1 + k·(target/mean − 1), computed from the settings the frame was captured with. The product is split exposure-first
(gain stays 0 dB until exposure reaches its upper limit, then gain supplies the rest).

The rule is asymmetric by construction: a saturated frame (mean 255) shrinks the product by only 1 − k/2 = 0.9 per
frame, while a dark frame can raise it many-fold; `min_mean` (a code value) keeps black frames finite.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import math

import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.controllers.base import Controller, Settings
from expoctl.controllers.registry import register_controller
from expoctl.controllers.metrics import luma_uint8
from expoctl.config_reader import Section, read_config

_DB_PER_LN = 20.0 / math.log(10.0)

@dataclass(frozen=True)
class MeanIntensityConfig:
    """`controllers.mean_intensity`."""

    k: float = 0.2
    target_mean: float = 127.5  # 8-bit grey (gamma domain, as delivered)
    min_mean: float = 1.0  # floor on the measured mean (code values) so a black frame gives a finite step
    exposure_lower_us: float = EXPOSURE_US_MIN
    exposure_upper_us: float = EXPOSURE_US_MAX
    gain_lower_db: float = GAIN_DB_MIN
    gain_upper_db: float = GAIN_DB_MAX

    def check(self, r: Section) -> None:
        """Bounds and the rules between keys (read_config runs it once every key has the right type)."""
        checks = [
            (0.0 < self.k <= 1.0, "k", "must be in (0, 1]"),
            (0.0 < self.target_mean < 255.0, "target_mean", "must be in (0, 255)"),
            (0.0 < self.min_mean <= self.target_mean, "min_mean", "must be in (0, target_mean]"),
            (EXPOSURE_US_MIN <= self.exposure_lower_us < self.exposure_upper_us <= EXPOSURE_US_MAX, "exposure_upper_us", f"need {EXPOSURE_US_MIN} <= exposure_lower_us < exposure_upper_us <= {EXPOSURE_US_MAX}"),
            (GAIN_DB_MIN <= self.gain_lower_db <= self.gain_upper_db <= GAIN_DB_MAX, "gain_upper_db", f"need {GAIN_DB_MIN} <= gain_lower_db <= gain_upper_db <= {GAIN_DB_MAX}"),
        ]
        for ok, key, problem in checks:
            if not ok:
                r.problem(key, problem)


def split_exposure_first(ln_product: float, t_lo: float, t_hi: float, g_lo: float, g_hi: float) -> Settings:
    """Product P = t·10^(g/20) (µs) → settings: exposure takes P at gain g_lo up to t_hi, then gain rises."""
    t = float(np.clip(math.exp(ln_product - g_lo / _DB_PER_LN), t_lo, t_hi))
    g = float(np.clip((ln_product - math.log(t)) * _DB_PER_LN, g_lo, g_hi))
    return Settings(g, t).clamped()


@register_controller("mean_intensity", config=MeanIntensityConfig, label="Mean intensity", colour="#e377c2", rank=40)
class MeanIntensityController(Controller):
    name = "mean_intensity"

    def __init__(self, config: MeanIntensityConfig | dict | None = None):
        """`config`: the typed config, or its section as a mapping (read and checked here)."""
        if not isinstance(config, MeanIntensityConfig):
            config = read_config(MeanIntensityConfig, config, "controllers.mean_intensity")
        p = self.config = config

    def reset(self, initial: Settings) -> None:  # stateless: every step uses the frame's own settings
        pass

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        p = self.config
        s = applied.clamped()
        mean = max(float(luma_uint8(image).mean()), p.min_mean)
        factor = 1.0 + p.k * (p.target_mean / mean - 1.0)  # ≥ 1 − k > 0
        ln_product = math.log(s.exposure_us) + s.gain_db / _DB_PER_LN + math.log(factor)
        return split_exposure_first(
            ln_product, p.exposure_lower_us, p.exposure_upper_us, p.gain_lower_db, p.gain_upper_db
        )
