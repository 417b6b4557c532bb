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
- Results are clamped to the camera ranges (0–30 dB, 19–30000 µs: the camera's own exposure floor).
- Randomness comes from a generator seeded per (sequence seed, frame index), so any frame's perturbation can be
  reproduced on its own, independent of how many frames came before or which process rendered it.

Beyond the paper (off unless `excursion_probability` > 0): **large excursions**. The quadrant cycle keeps camera 2
within about ±1 EV of camera 1, so the training data never show the network a badly exposed frame, and in closed
loop its step in such states is unconstrained (`benchmarks/archive/saturation_recovery.py`). With excursions, the frames are
cut into blocks of `excursion_frames`; each block is, with probability `excursion_probability`, an excursion: for
the whole block camera 2's exposure product is camera 1's × 2^(±m), m ~ U[`excursion_ev`], the sign drawn per block
(split exposure first: camera 1's gain is kept while the exposure time has range, then gain moves). A block's draw
is seeded by (sequence seed, block index) alone, so any frame's settings still reproduce on their own. Labels of
those time steps come from the best image in the window as always, mostly camera 1's, so the network's inputs from
an over- or under-exposed camera 2 are paired with targets back near the well-exposed settings.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, GAIN_DB_MAX, SENSOR_EXPOSURE_US_MIN
from expoctl.config_reader import Problems, Section
from expoctl.controllers.base import Settings

#: sign of (gain, exposure) change per frame index modulo 4: ++, +-, -+, -- (all four quadrants, one per frame)
QUADRANT_SIGNS: tuple[tuple[int, int], ...] = ((+1, +1), (+1, -1), (-1, +1), (-1, -1))

#: stream id mixed into per-frame seeds so perturbation draws never collide with sensor-noise draws
_PERTURBATION_STREAM = 0x5E7
_EXCURSION_STREAM = 0xE8C


@dataclass(frozen=True)
class PerturbationConfig:
    """Parameters of camera 2's perturbation (config group `rig.perturbation`)."""

    max_fraction: float = 0.5
    zero_gain_threshold_db: float = 0.5
    zero_gain_add_db: tuple[float, float] = (1.0, 6.0)
    zero_gain_add_in_down_quadrants: bool = False
    excursion_probability: float = 0.0  # share of blocks that are excursions (0 = the paper's protocol)
    excursion_ev: tuple[float, float] = (2.0, 5.0)  # |offset| of camera 2's exposure product from camera 1's, EV
    excursion_frames: int = 6  # block length

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "rig.perturbation",
                  problems: Problems | None = None) -> "PerturbationConfig":
        r = Section(d, key, problems)
        cfg = cls(
            max_fraction=r.number("max_fraction", cls.max_fraction, min=0.0, below=1.0),  # paper: 0.5
            zero_gain_threshold_db=r.number("zero_gain_threshold_db", cls.zero_gain_threshold_db, min=0.0,
                                            max=GAIN_DB_MAX, unit="dB"),
            zero_gain_add_db=r.pair("zero_gain_add_db", cls.zero_gain_add_db, min=0.0, max=GAIN_DB_MAX, unit="dB"),
            zero_gain_add_in_down_quadrants=r.boolean("zero_gain_add_in_down_quadrants",
                                                      cls.zero_gain_add_in_down_quadrants),
            excursion_probability=r.number("excursion_probability", cls.excursion_probability, min=0.0, max=1.0),
            # 15 EV: the whole exposure × gain range of the camera is about 14 EV
            excursion_ev=r.pair("excursion_ev", cls.excursion_ev, above=0.0, max=15.0, unit="EV"),
            excursion_frames=r.integer("excursion_frames", cls.excursion_frames, min=1),
        )
        r.done()
        return cfg

    def to_dict(self) -> dict:
        d = asdict(self)
        d["zero_gain_add_db"] = list(self.zero_gain_add_db)
        d["excursion_ev"] = list(self.excursion_ev)
        return d


def quadrant(frame_index: int) -> tuple[int, int]:
    """(gain sign, exposure sign) for a frame: the four quadrants in turn, repeating every four frames."""
    return QUADRANT_SIGNS[frame_index % 4]


def perturbation_rng(seed: int, frame_index: int) -> np.random.Generator:
    """The generator for one frame's perturbation draws (independent of every other frame's)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), _PERTURBATION_STREAM, int(frame_index)]))


def excursion_offset_ev(frame_index: int, seed: int, cfg: PerturbationConfig) -> float:
    """Camera 2's excursion (EV from camera 1's exposure product) for `frame_index`; 0.0 outside excursions."""
    if cfg.excursion_probability <= 0.0:
        return 0.0
    block = int(frame_index) // cfg.excursion_frames
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), _EXCURSION_STREAM, block]))
    u_on, u_size, u_sign = rng.uniform(0.0, 1.0, size=3)
    if u_on >= cfg.excursion_probability:
        return 0.0
    lo, hi = cfg.excursion_ev
    return float((lo + (hi - lo) * u_size) * (1.0 if u_sign < 0.5 else -1.0))


def _scale_product(reference: Settings, offset_ev: float) -> Settings:
    """reference's exposure product × 2^offset_ev: exposure time first, keeping the gain while it has range."""
    exposure_us = float(np.clip(reference.exposure_us * 2.0 ** offset_ev, SENSOR_EXPOSURE_US_MIN, EXPOSURE_US_MAX))
    left_ev = offset_ev - float(np.log2(exposure_us / reference.exposure_us))  # what the exposure range could not take
    gain_db = reference.gain_db + left_ev * 20.0 * float(np.log10(2.0))
    return Settings(gain_db, exposure_us).clamped()


def perturb(reference: Settings, frame_index: int, seed: int, cfg: PerturbationConfig = PerturbationConfig()) -> Settings:
    """Camera 2's settings for `frame_index`, given camera 1's settings for the same frame."""
    offset = excursion_offset_ev(frame_index, seed, cfg)
    if offset != 0.0:
        return _scale_product(reference, offset)
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
