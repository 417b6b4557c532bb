"""The paper's data-collection protocol: camera 2 gets camera 1's settings, perturbed.

Tomasi et al. (RA-L 2021, §III-B): camera 1 runs a reference controller; camera 2's gain and exposure are each
multiplied by 1 ± U[0, a] (a = 0.5), independently, with the signs cycling through the four quadrants
(gain up/down × exposure up/down), one quadrant per frame, repeating every four frames. Scaling cannot move a
0 dB gain, so when camera 1's gain is (near) zero a small random gain is *added* instead.

Our choices where the paper is silent (documented so a reader can check them):
- "Near zero" is gain < `zero_gain_threshold_db` (default 0.5 dB; an exposure-first AE sits at exactly 0 dB outdoors).
- The added gain is U[`zero_gain_add_db`] = U[1, 6] dB by default. 6 dB matches the largest upward scaling of
  exposure (×1.5 ≈ +3.5 dB) within a factor of two; the authors' code used a random integer 5–10 dB below 5 dB,
  which biased camera 2 to be ~1 EV brighter — we keep it smaller.
- In gain-*down* quadrants a near-zero gain cannot go lower; it stays at camera 1's gain, so the quadrant pattern
  survives (set `zero_gain_add_in_down_quadrants: true` to add the random gain in every quadrant, as the authors did).
- Results are clamped to the camera ranges (0–30 dB, 75–30000 µs).
- Randomness comes from a generator seeded per (sequence seed, frame index), so any frame's perturbation can be
  reproduced on its own, independent of how many frames came before or which process rendered it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from expoctl.controllers.base import Settings
from expoctl.errors import ConfigError

#: sign of (gain, exposure) change per frame index modulo 4: ++, +-, -+, -- (all four quadrants, one per frame)
QUADRANT_SIGNS: tuple[tuple[int, int], ...] = ((+1, +1), (+1, -1), (-1, +1), (-1, -1))

#: stream id mixed into per-frame seeds so perturbation draws never collide with sensor-noise draws
_PERTURBATION_STREAM = 0x5E7


@dataclass(frozen=True)
class PerturbationConfig:
    """Parameters of camera 2's perturbation (config group `rig.perturbation`)."""

    max_fraction: float = 0.5
    zero_gain_threshold_db: float = 0.5
    zero_gain_add_db: tuple[float, float] = (1.0, 6.0)
    zero_gain_add_in_down_quadrants: bool = False

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "rig.perturbation") -> "PerturbationConfig":
        d = dict(d or {})
        known = {"max_fraction", "zero_gain_threshold_db", "zero_gain_add_db", "zero_gain_add_in_down_quadrants"}
        for k in d:
            if k not in known:
                raise ConfigError(f"{key}.{k}", f"unknown key (expected one of {sorted(known)})")
        kw: dict = {}
        for name in ("max_fraction", "zero_gain_threshold_db"):
            if name in d:
                kw[name] = _number(d[name], f"{key}.{name}")
        if "zero_gain_add_db" in d:
            v = d["zero_gain_add_db"]
            if not isinstance(v, (list, tuple)) or len(v) != 2:
                raise ConfigError(f"{key}.zero_gain_add_db", f"expected [low_db, high_db], got {v!r}")
            kw["zero_gain_add_db"] = (_number(v[0], f"{key}.zero_gain_add_db"), _number(v[1], f"{key}.zero_gain_add_db"))
        if "zero_gain_add_in_down_quadrants" in d:
            v = d["zero_gain_add_in_down_quadrants"]
            if not isinstance(v, bool):
                raise ConfigError(f"{key}.zero_gain_add_in_down_quadrants", f"expected true/false, got {v!r}")
            kw["zero_gain_add_in_down_quadrants"] = v
        out = cls(**kw)
        out.validate(key)
        return out

    def validate(self, key: str = "rig.perturbation") -> None:
        if not 0.0 <= self.max_fraction < 1.0:
            raise ConfigError(f"{key}.max_fraction", f"must be in [0, 1) (paper: 0.5), got {self.max_fraction}")
        if not 0.0 <= self.zero_gain_threshold_db <= 30.0:
            raise ConfigError(f"{key}.zero_gain_threshold_db", f"must be in [0, 30] dB, got {self.zero_gain_threshold_db}")
        lo, hi = self.zero_gain_add_db
        if not 0.0 <= lo <= hi <= 30.0:
            raise ConfigError(f"{key}.zero_gain_add_db", f"need 0 <= low <= high <= 30 dB, got [{lo}, {hi}]")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["zero_gain_add_db"] = list(self.zero_gain_add_db)
        return d


def quadrant(frame_index: int) -> tuple[int, int]:
    """(gain sign, exposure sign) for a frame: the four quadrants in turn, repeating every four frames."""
    return QUADRANT_SIGNS[frame_index % 4]


def perturbation_rng(seed: int, frame_index: int) -> np.random.Generator:
    """The generator for one frame's perturbation draws (independent of every other frame's)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), _PERTURBATION_STREAM, int(frame_index)]))


def perturb(reference: Settings, frame_index: int, seed: int, cfg: PerturbationConfig = PerturbationConfig()) -> Settings:
    """Camera 2's settings for `frame_index`, given camera 1's settings for the same frame."""
    gain_sign, exposure_sign = quadrant(frame_index)
    rng = perturbation_rng(seed, frame_index)
    # draw in a fixed order so each quantity's value does not depend on which branch is taken
    u_gain, u_exposure, u_add = rng.uniform(0.0, 1.0, size=3)
    exposure_us = reference.exposure_us * (1.0 + exposure_sign * cfg.max_fraction * u_exposure)
    if reference.gain_db < cfg.zero_gain_threshold_db:
        lo, hi = cfg.zero_gain_add_db
        add = gain_sign > 0 or cfg.zero_gain_add_in_down_quadrants
        gain_db = reference.gain_db + (lo + (hi - lo) * u_add if add else 0.0)
    else:
        gain_db = reference.gain_db * (1.0 + gain_sign * cfg.max_fraction * u_gain)
    return Settings(float(gain_db), float(exposure_us)).clamped()


def _number(v, key: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(key, f"expected a number, got {v!r}")
    return float(v)
