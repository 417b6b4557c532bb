"""The environment's two action modes: an action ↔ the camera settings it commands (docs/benchmark.md).

- `absolute`: [gain, exposure] normalised as the paper's network outputs them (`expoctl.camera.ranges`): gain g/30;
  exposure on the `exposure_scale` scale ("log": EV above 75 µs over the 8.64-stop range, the default, because under
  the paper's "linear" scale every daylight exposure sits in [0, 0.03]; or "linear"). [0, 1]² is the network's range
  (0–30 dB, 75 µs–30 ms); the exposure axis extends below 0 to the sensor's floor (19 µs, which AG+AE uses), so every
  setting the camera can take is an action and a built-in controller can be replayed exactly.
- `settings`: [gain_db, exposure_us] in the camera's units (0–30 dB, 19 µs–30 ms): any controller's command as is.
- `ev_step`: one number, a step in EV (log2 of the exposure product t·10^(g/20)) from the settings the current frame
  was exposed with, bounded by ±`max_ev_step`, spent exposure first as AG+AE does (`split_exposure_first`: gain stays
  at 0 dB until exposure reaches 30 ms).

Actions are float64, so that `action_of` can give an action that maps back to exactly the settings a controller
commands: that is what makes a controller driven through the environment reproduce evaluate byte for byte
(`expoctl.bench.policy`). `settings` mode does so for every command; `ev_step` for every exposure-first command within
±max_ev_step of the current frame's (AG+AE's: its steps are rate-limited to 0.51 EV); `absolute` cannot in general:
normalised floats are coarser than the settings they map to (under the log scale one action ulp moves a long exposure
by about four of its ulps, and gain g = 30·x skips every other float below 15 dB), so a replayed command may land a
few ulps away. Actions outside the space are clipped to it; the
resulting settings are clamped to the camera's range (`Settings.clamped`), as the closed loop clamps a controller's.
"""

from __future__ import annotations

import math

import numpy as np

from expoctl.camera import ranges
from expoctl.controllers.agae import ln_exposure_product, split_exposure_first
from expoctl.controllers.base import Settings

ACTION_MODES = ("absolute", "settings", "ev_step")
_MAX_ULPS = 256  # how far `action_of` searches around the rounded inverse for an exact preimage


class ActionMap:
    """One action mode: its gymnasium space, action → settings (`settings_of`) and an exact inverse (`action_of`)."""

    def __init__(self, mode: str, exposure_scale: str = "log", max_ev_step: float = 1.0):
        from gymnasium import spaces

        from expoctl.bench.errors import EnvArgumentError

        if mode not in ACTION_MODES:
            raise EnvArgumentError(f"action: must be one of {', '.join(ACTION_MODES)}, got {mode!r}")
        if exposure_scale not in ranges.EXPOSURE_SCALES:
            raise EnvArgumentError(f"exposure_scale: must be one of {', '.join(ranges.EXPOSURE_SCALES)}, "
                                   f"got {exposure_scale!r}")
        if not (isinstance(max_ev_step, (int, float)) and math.isfinite(max_ev_step) and 0 < max_ev_step <= 20):
            raise EnvArgumentError(f"max_ev_step: must be a number of EV in (0, 20], got {max_ev_step!r}")
        self.mode, self.exposure_scale, self.max_ev_step = mode, exposure_scale, float(max_ev_step)
        if mode == "absolute":
            low_e = float(ranges.exposure_to_norm(ranges.SENSOR_EXPOSURE_US_MIN, exposure_scale))
            self.space = spaces.Box(np.array([0.0, low_e]), np.array([1.0, 1.0]), dtype=np.float64)
        elif mode == "settings":
            self.space = spaces.Box(np.array([ranges.GAIN_DB_MIN, ranges.SENSOR_EXPOSURE_US_MIN]),
                                    np.array([ranges.GAIN_DB_MAX, ranges.EXPOSURE_US_MAX]), dtype=np.float64)
        else:
            self.space = spaces.Box(-self.max_ev_step, self.max_ev_step, shape=(1,), dtype=np.float64)

    def settings_of(self, action, applied: Settings) -> Settings:
        """The settings `action` commands for the next frame; `applied`: what the current frame was exposed with."""
        a = np.clip(self._checked(action), self.space.low, self.space.high)
        if self.mode == "absolute":
            gain = float(ranges.norm_to_gain(a[0]))
            exposure = float(ranges.norm_to_exposure(a[1], self.exposure_scale, clamp=False))
            return Settings(gain, exposure).clamped()
        if self.mode == "settings":
            return Settings(float(a[0]), float(a[1])).clamped()
        return split_exposure_first(ln_exposure_product(applied) + float(a[0]) * math.log(2.0))

    def action_of(self, settings: Settings, applied: Settings) -> np.ndarray:
        """An action that `settings_of` maps to exactly `settings` (clamped to the camera's range first), searched
        within a few hundred ulps of the rounded inverse; ValueError when there is none (see the module doc: in
        absolute mode, often; in ev_step mode, a step beyond ±max_ev_step or settings off the exposure-first curve)."""
        target = settings.clamped()
        if self.mode == "absolute":
            g0 = float(ranges.gain_to_norm(target.gain_db))
            e0 = float(ranges.exposure_to_norm(target.exposure_us, self.exposure_scale))
            g = _preimage(lambda x: self.settings_of([x, e0], applied).gain_db, g0, target.gain_db)
            e = _preimage(lambda x: self.settings_of([g0, x], applied).exposure_us, e0, target.exposure_us)
            if g is not None and e is not None:
                return np.array([g, e], dtype=np.float64)
        elif self.mode == "settings":
            return np.array([target.gain_db, target.exposure_us], dtype=np.float64)
        else:
            step = (ln_exposure_product(target) - ln_exposure_product(applied)) / math.log(2.0)
            if abs(step) <= self.max_ev_step:
                found = _preimage(lambda x: self.settings_of([x], applied), step, target)
                if found is not None:
                    return np.array([found], dtype=np.float64)
        raise ValueError(f"no {self.mode} action gives exactly {target} from {applied} "
                         f"(exposure_scale {self.exposure_scale!r}, max_ev_step {self.max_ev_step})")

    def _checked(self, action) -> np.ndarray:
        try:
            a = np.asarray(action, dtype=np.float64).reshape(self.space.shape)
        except (TypeError, ValueError):
            raise ValueError(f"action: must be {self.space.shape[0]} numbers ({self.mode} mode), "
                             f"got {action!r}") from None
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action: must be finite, got {a.tolist()} ({self.mode} mode)")
        return a


def _preimage(f, x0: float, want):
    """The float nearest `x0` (by ulps, outwards) with f(x) == want; None if none within _MAX_ULPS."""
    if f(x0) == want:
        return x0
    lo = hi = x0
    for _ in range(_MAX_ULPS):
        lo, hi = np.nextafter(lo, -np.inf), np.nextafter(hi, np.inf)
        for x in (float(lo), float(hi)):
            if f(x) == want:
                return x
    return None
