"""Statistics of an auto-exposure trace through a tunnel: what the real camera's AG+AE is fitted to and checked against.

A trace is the per-frame exposure product of one camera, EV = log2(exposure_us) + gain_db / 6.02 (+1 EV = twice
the signal), at consecutive frames. The statistics depend on the loop's speed, not on how bright the scene is:

- **exit** (the product falls from its in-tunnel peak to the outdoor level):
  - `largest_reducing_step_ev`: the largest single-frame decrease;
  - `mean_rate_80_ev_per_frame`: 80 % of the drop divided by the frames the loop needs to cover it;
  - `frames_80` and `frames_to_settle` (to within 0.1 EV of the outdoor level);
  - `onset_frames`: frames from the peak until a step first reaches 90 % of the largest reducing step (the ramp).
- **entry** (the product rises into the tunnel): `first_step_ev` (the largest increase) and `shrink_ratio`, the
  median ratio of consecutive increases over the decay that follows it (a first-order loop that corrects a fraction
  k of its error per frame shrinks them by 1 − k).

The recorded trace (Tomasi et al.'s rig, `data_32`) reads: exit largest step 0.178 EV, mean rate 0.11 EV/frame over
80 % of a ~5 EV drop, onset ~9 frames; entry first step 0.51 EV, then a shrink ratio of ~0.88 per frame.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

EV_PER_DB = 1.0 / (20.0 * math.log10(2.0))  # 1 EV = 6.02 dB of gain


def ev_trace(exposure_us, gain_db) -> np.ndarray:
    """Exposure product in EV (log2 µs + gain in EV) per frame."""
    t = np.asarray(exposure_us, dtype=np.float64)
    g = np.asarray(gain_db, dtype=np.float64)
    if t.shape != g.shape or t.ndim != 1:
        raise ValueError(f"exposure and gain must be 1-D and of one length, got {t.shape} and {g.shape}")
    if not (np.all(np.isfinite(t)) and np.all(t > 0) and np.all(np.isfinite(g))):
        raise ValueError("exposure must be finite and > 0 µs and gain finite at every frame")
    return np.log2(t) + g * EV_PER_DB


@dataclass(frozen=True)
class ExitStats:
    peak_frame: int
    drop_ev: float
    largest_reducing_step_ev: float
    mean_rate_80_ev_per_frame: float
    frames_80: int
    frames_to_settle: int
    onset_frames: int

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class EntryStats:
    first_step_frame: int
    first_step_ev: float
    shrink_ratio: float
    n_ratios: int

    def to_dict(self) -> dict:
        return asdict(self)


def exit_stats(ev: np.ndarray, outdoor_frames: int = 15, settle_tol_ev: float = 0.1) -> ExitStats:
    """Exit statistics of a trace that peaks (in the tunnel) and falls to an outdoor level.

    The outdoor level is the median of the last `outdoor_frames` frames; the peak is the last frame at the trace's
    highest EV. Raises ValueError if the trace does not fall by at least 1 EV."""
    ev = np.asarray(ev, dtype=np.float64)
    if ev.ndim != 1 or ev.size < outdoor_frames + 3:
        raise ValueError(f"need a 1-D trace of more than {outdoor_frames + 2} frames, got shape {ev.shape}")
    outdoor = float(np.median(ev[-outdoor_frames:]))
    peak = int(ev.size - 1 - np.argmax(ev[::-1]))  # the last frame at the highest product: where the fall starts
    drop = float(ev[peak] - outdoor)
    if drop < 1.0:
        raise ValueError(f"the trace falls by only {drop:.2f} EV after its peak: no tunnel exit to measure")
    after = ev[peak:]
    steps = -np.diff(after)  # reducing steps are positive here
    level_80 = ev[peak] - 0.8 * drop
    frames_80 = int(np.flatnonzero(after <= level_80)[0])
    settle = np.flatnonzero(after <= outdoor + settle_tol_ev)
    frames_to_settle = int(settle[0]) if settle.size else len(after) - 1
    largest = float(steps[:max(frames_to_settle, 1)].max())
    onset = int(np.flatnonzero(steps >= 0.9 * largest)[0]) + 1
    return ExitStats(peak, drop, largest, 0.8 * drop / frames_80, frames_80, frames_to_settle, onset)


def entry_stats(ev: np.ndarray, min_step_ev: float = 0.02, max_ratios: int = 12) -> EntryStats:
    """Entry statistics: the largest increase, then the median ratio of consecutive increases while they decay.

    Ratios are taken from the frame after the largest increase, over at most `max_ratios` consecutive pairs of
    increases larger than `min_step_ev` (below that the 0.1 dB / 1 % quantisation of real settings dominates)."""
    ev = np.asarray(ev, dtype=np.float64)
    steps = np.diff(ev)
    if steps.size < 3 or steps.max() <= min_step_ev:
        raise ValueError("the trace never rises: no tunnel entry to measure")
    k0 = int(np.argmax(steps))
    ratios = []
    for k in range(k0 + 1, min(steps.size - 1, k0 + 1 + max_ratios)):
        if steps[k] <= min_step_ev or steps[k + 1] <= min_step_ev:
            break
        ratios.append(steps[k + 1] / steps[k])
    ratio = float(np.median(ratios)) if ratios else float("nan")
    return EntryStats(k0 + 1, float(steps[k0]), ratio, len(ratios))


def step_table(ev: np.ndarray) -> dict:
    """Per-direction statistics of the single-frame changes (|step| > 0.005 EV counts as a move): count, median,
    90th percentile and maximum, in EV per frame."""
    steps = np.diff(np.asarray(ev, dtype=np.float64))
    out = {}
    for name, s in (("up", steps[steps > 0.005]), ("down", -steps[steps < -0.005])):
        out[name] = {"n": int(s.size), "median": float(np.median(s)) if s.size else 0.0,
                     "p90": float(np.percentile(s, 90)) if s.size else 0.0, "max": float(s.max()) if s.size else 0.0}
    return out
