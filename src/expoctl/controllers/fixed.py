"""Fixed-parameter controller (docs/controllers.md): one gain/exposure for the whole run, a lower bound that fails
by construction at tunnel portals.

Two ways to choose the values:
(a) mode "agae_warmup" (default): AG+AE drives the first `warmup_frames` frames; its command at the end of the
    warm-up is locked for the rest of the run ("the values AG+AE settled on in the first N frames").
(b) best value of a grid search on the first frame: this needs counterfactual renders of frame 0 (simulator only),
    so the evaluation harness calls `grid_search_first_frame(render, gains_db, exposures_us, score)` and builds a
    mode "manual" controller with the result. The default score is the ORB keypoint count (the paper's feature
    objective); exposure is capped at 30 ms like every setting here.
mode "manual": `gain_db` and `exposure_us` from config.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from collections.abc import Callable, Iterable

import cv2
import numpy as np

from expoctl.controllers.agae import AgAeConfig, AgAeController
from expoctl.controllers.base import Controller, Settings
from expoctl.controllers.registry import register_controller
from expoctl.controllers.metrics import luma_uint8
from expoctl.config_reader import Section, read_config

@dataclass(frozen=True)
class FixedConfig:
    """`controllers.fixed`."""

    mode: str = "agae_warmup"  # agae_warmup | manual
    warmup_frames: int = 30
    gain_db: float = 0.0  # manual mode
    exposure_us: float = 5000.0  # manual mode
    agae: AgAeConfig = field(default_factory=AgAeConfig)  # AG+AE used during the warm-up (controllers.agae keys)

    def check(self, r: Section) -> None:
        """Bounds and the rules between keys (read_config runs it once every key has the right type)."""
        checks = [
            (self.mode in ("agae_warmup", "manual"), "mode", "must be agae_warmup or manual"),
            (self.warmup_frames >= 1, "warmup_frames", "must be >= 1"),
            (0.0 <= self.gain_db <= 30.0, "gain_db", "must be in [0, 30] dB"),
            (75.0 <= self.exposure_us <= 30000.0, "exposure_us", "must be in [75, 30000] µs"),
        ]
        for ok, key, problem in checks:
            if not ok:
                r.problem(key, problem)


@register_controller("fixed", config=FixedConfig, label="Fixed", colour="#7f7f7f", rank=50)
class FixedController(Controller):
    name = "fixed"

    def __init__(self, config: FixedConfig | dict | None = None):
        """`config`: the typed config, or its section as a mapping (read and checked here)."""
        if not isinstance(config, FixedConfig):
            config = read_config(FixedConfig, config, "controllers.fixed")
        p = self.config = config
        self._agae = AgAeController(p.agae, config_key="controllers.fixed.agae") if p.mode == "agae_warmup" else None
        self.reset(Settings(p.gain_db, p.exposure_us))

    def reset(self, initial: Settings) -> None:
        self._frame = 0
        if self._agae is None:
            self._locked: Settings | None = Settings(self.config.gain_db, self.config.exposure_us).clamped()
        else:
            self._locked = None
            self._agae.reset(initial)

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        if self._locked is not None:
            return self._locked
        self._frame += 1
        command = self._agae.update(image, applied)
        if self._frame >= self.config.warmup_frames:
            self._locked = command
        return command

    @property
    def locked(self) -> Settings | None:
        """The locked settings (None while AG+AE is still warming up)."""
        return self._locked


def orb_keypoint_count(image: np.ndarray, n_features: int = 2000) -> float:
    """Number of ORB keypoints on the luma image (default score of the first-frame grid search)."""
    orb = cv2.ORB_create(nfeatures=n_features)
    return float(len(orb.detect(luma_uint8(image), None)))


def grid_search_first_frame(
    render: Callable[[Settings], np.ndarray],
    gains_db: Iterable[float],
    exposures_us: Iterable[float],
    score: Callable[[np.ndarray], float] = orb_keypoint_count,
) -> Settings:
    """Best (gain, exposure) on a grid for the first frame: `render(settings)` returns frame 0 captured with them.
    Ties go to the lowest gain, then the shortest exposure (less noise, less blur)."""
    best: tuple[float, float, float] | None = None
    best_settings = None
    for g in sorted(float(v) for v in gains_db):
        for t in sorted(float(v) for v in exposures_us):
            s = Settings(g, t).clamped()
            value = float(score(render(s)))
            value = value if np.isfinite(value) else -np.inf
            key = (value, -s.gain_db, -s.exposure_us)
            if best is None or key > best:
                best, best_settings = key, s
    if best_settings is None:
        raise ValueError("grid_search_first_frame: empty gain or exposure grid")
    return best_settings
