"""AG+AE: a model of the FLIR Blackfly S (Spinnaker) built-in auto gain + auto exposure (docs/controllers.md).

Loop, per frame (docs/controllers.md, AG+AE model: the model's steps and how its constants were fitted):
1. Meter m = mean of the *linear* image (camera response inverted) over the metering region (average / spot ≈ 3 % /
   partial ≈ 11 %, centred, or a fractional ROI).
2. The frame was shot with a known product P_f = t·10^(g/20) (the camera knows its own settings, like chunk data),
   so the product that would have hit the target is ln P* = ln P_f + ln(target·2^EVcomp / m).
3. The internal command moves towards it: ln P ← ln P + (1 − damping)·(ln P* − ln P), with a brightening step
   clipped to `max_brighten_ev_per_frame` and a darkening step to `max_darken_ev_per_frame`. Using the frame's own
   P_f (not the last command) keeps the loop from oscillating through its latency; in steady state this is exactly
   the spec's ln P ← ln P + (1 − damping)·ln(target/m). A saturated frame reads m ≤ 1, so the error is
   under-estimated and the darkening limit sets the pace at tunnel exits.
   Defaults fitted to the real camera's recorded tunnel pass (`expoctl.controllers.ae_trace`, benchmarks/archive/agae_fit.py):
   consecutive entry steps shrink by 0.873 per frame → damping 0.873 (the loop corrects 12.7 % of its error per
   frame); the largest exit step was 0.178 EV → the darkening limit; the entry's one 0.507 EV step → the brightening
   limit (it did not bind there, so it is a lower bound). The old loop (damping 0.2, ±0.5 EV) is 3–5× faster at exits
   than the real camera; it stays reachable as config.
4. Split P exposure-first ("Gain" priority in Spinnaker's misleading naming): gain stays at its lower limit until
   exposure reaches its upper limit (30 ms), then gain rises. The alternative "gain_first" priority holds exposure at
   `gain_first_exposure_us` (Spinnaker default 5 ms) and moves gain first.
5. Latency: the caller applies our output at t+1 (actuation delay); on top of it the AE computes from the *previous*
   frame (`internal_latency_frames`, default 1), so a change seen at frame t first affects frame t+2.
Black frames are metered with a floor (m ≥ `min_linear_mean`), so the error stays finite and the step limit applies.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, GAIN_DB_MAX, GAIN_DB_MIN, SENSOR_EXPOSURE_US_MIN
from expoctl.camera.response import response_from_config
from expoctl.controllers.base import Controller, Settings
from expoctl.controllers.registry import register_controller
from expoctl.controllers.metrics import METERING_AREA_FRACTION, ResponseInverse, metered_linear_mean
from expoctl.config_reader import Section, read_config

_DB_PER_LN = 20.0 / math.log(10.0)  # gain dB per natural-log unit of linear gain

@dataclass(frozen=True)
class AgAeConfig:
    """`controllers.agae` (also `controllers.fixed.agae`, the fixed controller's warm-up)."""

    target_grey_pct: float = 18.0  # linear, % of full scale; 18 % ≈ code 118 through sRGB [our assumption; read it back]
    ev_compensation: float = 0.0  # EV, Spinnaker range −3 … +3
    # fitted to the recorded trace (module doc); the SDK header's default is 0.2, the BFS web page's 0.5
    damping: float = 0.873  # fraction of the log error left after one frame (entry steps shrink by this ratio)
    max_brighten_ev_per_frame: float = 0.51  # recorded entry: one 0.507 EV step (the largest increase)
    max_darken_ev_per_frame: float = 0.178  # recorded exit: the largest single-frame decrease
    metering_mode: str = "average"  # average | spot | partial
    roi: tuple[float, ...] | None = None  # optional [x0, y0, x1, y1] fractions of width/height; overrides metering_mode
    priority: str = "exposure_first"  # exposure_first (Spinnaker "Gain") | gain_first (Spinnaker "ExposureTime")
    gain_first_exposure_us: float = 5000.0
    exposure_lower_us: float = SENSOR_EXPOSURE_US_MIN  # the camera's own floor, below the network's 75 µs
    exposure_upper_us: float = EXPOSURE_US_MAX
    gain_lower_db: float = GAIN_DB_MIN
    gain_upper_db: float = GAIN_DB_MAX
    internal_latency_frames: int = 1  # AE computes from the frame before the newest one
    min_linear_mean: float = 1e-4  # metering floor for black frames (keeps the log error finite)
    # the response the AE inverts to meter linear light: keep equal to the sensor's response keys (the config
    # interpolates them; a real camera meters before gamma, we only see the delivered 8-bit image)
    response_curve: str = "srgb"
    response_gamma: float = 2.2
    response_gamma_rgb: tuple[float, ...] | None = None  # per channel [R, G, B] or None (camera.response)
    response_pedestal_rgb: tuple[float, ...] = (0.0, 0.0, 0.0)
    white_balance_rgb: tuple[float, ...] = (1.0, 1.0, 1.0)

    def check(self, r: Section) -> None:
        """The rules between keys and the bounds (read_config runs it once every key has the right type)."""
        checks = [
            (0.0 < self.target_grey_pct < 100.0, "target_grey_pct", "must be in (0, 100) percent of full scale"),
            (-3.0 <= self.ev_compensation <= 3.0, "ev_compensation", "must be in [-3, 3] EV"),
            (0.0 <= self.damping < 1.0, "damping", "must be in [0, 1)"),
            (self.max_brighten_ev_per_frame > 0.0, "max_brighten_ev_per_frame", "must be > 0 EV per frame"),
            (self.max_darken_ev_per_frame > 0.0, "max_darken_ev_per_frame", "must be > 0 EV per frame"),
            (self.metering_mode in METERING_AREA_FRACTION, "metering_mode",
             f"must be one of {sorted(METERING_AREA_FRACTION)}"),
            (self.roi is None or (len(self.roi) == 4 and 0.0 <= self.roi[0] < self.roi[2] <= 1.0
                                  and 0.0 <= self.roi[1] < self.roi[3] <= 1.0), "roi",
             "must be null or [x0, y0, x1, y1] with 0 <= x0 < x1 <= 1 and 0 <= y0 < y1 <= 1"),
            (self.priority in ("exposure_first", "gain_first"), "priority", "must be exposure_first or gain_first"),
            (SENSOR_EXPOSURE_US_MIN <= self.exposure_lower_us <= self.exposure_upper_us <= EXPOSURE_US_MAX,
             "exposure_upper_us",
             f"need {SENSOR_EXPOSURE_US_MIN} <= exposure_lower_us <= exposure_upper_us <= {EXPOSURE_US_MAX}"),
            (GAIN_DB_MIN <= self.gain_lower_db <= self.gain_upper_db <= GAIN_DB_MAX, "gain_upper_db",
             f"need {GAIN_DB_MIN} <= gain_lower_db <= gain_upper_db <= {GAIN_DB_MAX}"),
            (self.exposure_lower_us <= self.gain_first_exposure_us <= self.exposure_upper_us,
             "gain_first_exposure_us", "must lie within [exposure_lower_us, exposure_upper_us]"),
            (0 <= self.internal_latency_frames <= 10, "internal_latency_frames", "must be an integer in [0, 10]"),
            (0.0 < self.min_linear_mean < 1.0, "min_linear_mean", "must be in (0, 1)"),
        ]
        for ok, key, problem in checks:
            if not ok:
                r.problem(key, problem)
        r.problems.collect(response_from_config, self.response_keys(), r.key)  # names the response key

    def response_keys(self) -> dict:
        """The response keys as `expoctl.camera.response.response_from_config` reads them."""
        return {k: getattr(self, k) for k in RESPONSE_KEYS}


RESPONSE_KEYS = ("response_curve", "response_gamma", "response_gamma_rgb", "response_pedestal_rgb",
                 "white_balance_rgb")


def ln_exposure_product(s: Settings) -> float:
    """ln of the total exposure product t·10^(g/20) (t in µs): what brightness the settings ask for."""
    return math.log(s.exposure_us) + s.gain_db / _DB_PER_LN


def split_exposure_first(ln_p: float, t_lo: float = SENSOR_EXPOSURE_US_MIN, t_hi: float = EXPOSURE_US_MAX,
                         g_lo: float = GAIN_DB_MIN, g_hi: float = GAIN_DB_MAX) -> Settings:
    """Spend an exposure product on exposure time first (gain at g_lo until t reaches t_hi), within the limits."""
    t = float(np.clip(math.exp(ln_p - g_lo / _DB_PER_LN), t_lo, t_hi))
    g = float(np.clip((ln_p - math.log(t)) * _DB_PER_LN, g_lo, g_hi))
    return Settings(g, t).clamped()


@register_controller("agae", config=AgAeConfig, label="AG+AE", colour="#d62728", rank=10)
class AgAeController(Controller):
    """Model of the Blackfly S AG+AE loop. `response_inverse` maps uint8 images to linear [0, 1]; by default the
    inverse of the configured response curve (`expoctl.camera.response`, sRGB unless configured otherwise)."""

    name = "agae"

    def __init__(
        self,
        config: AgAeConfig | dict | None = None,
        response_inverse: ResponseInverse | None = None,
        config_key: str = "controllers.agae",
    ):
        """`config`: the typed config, or its section as a mapping (read and checked here, keys named under
        `config_key`)."""
        if not isinstance(config, AgAeConfig):
            config = read_config(AgAeConfig, config, config_key)
        p = self.config = config
        if response_inverse is None:
            response_inverse = response_from_config(p.response_keys(), config_key).uint8_to_linear
        self.response_inverse = response_inverse
        self.target_linear = p.target_grey_pct / 100.0 * 2.0 ** p.ev_compensation
        self._max_up_ln = p.max_brighten_ev_per_frame * math.log(2.0)
        self._max_down_ln = p.max_darken_ev_per_frame * math.log(2.0)
        # achievable range of ln P (P in µs × linear gain); the command never winds up beyond it
        self._ln_p_min = math.log(p.exposure_lower_us) + p.gain_lower_db / _DB_PER_LN
        self._ln_p_max = math.log(p.exposure_upper_us) + p.gain_upper_db / _DB_PER_LN
        self.reset(Settings(p.gain_lower_db, p.exposure_upper_us))

    # ------------------------------------------------------------------------------------------------ public API
    def reset(self, initial: Settings) -> None:
        s = initial.clamped()
        self._ln_p = float(np.clip(ln_exposure_product(s), self._ln_p_min, self._ln_p_max))
        self._pending: deque[float] = deque()  # ln P* of frames metered but not yet acted on (internal latency)

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        self._pending.append(self._ideal_ln_product(image, applied))
        if len(self._pending) > self.config.internal_latency_frames:
            ln_target = self._pending.popleft()
            step = (1.0 - self.config.damping) * (ln_target - self._ln_p)
            step = float(np.clip(step, -self._max_down_ln, self._max_up_ln))
            self._ln_p = float(np.clip(self._ln_p + step, self._ln_p_min, self._ln_p_max))
        return self.split(self._ln_p)

    # ------------------------------------------------------------------------------------------------ internals
    def metered_mean(self, image: np.ndarray) -> float:
        """Linear metered mean in [0, 1], floored at `min_linear_mean`."""
        p = self.config
        m = metered_linear_mean(image, self.response_inverse, p.metering_mode, p.roi)
        return max(m, p.min_linear_mean)

    def _ideal_ln_product(self, image: np.ndarray, applied: Settings) -> float:
        s = applied.clamped()
        return ln_exposure_product(s) + math.log(self.target_linear / self.metered_mean(image))

    def split(self, ln_p: float) -> Settings:
        """Distribute the product over exposure and gain according to the priority, within the limits."""
        p = self.config
        t_lo, t_hi = p.exposure_lower_us, p.exposure_upper_us
        g_lo, g_hi = p.gain_lower_db, p.gain_upper_db
        if p.priority == "exposure_first":
            return split_exposure_first(ln_p, t_lo, t_hi, g_lo, g_hi)
        else:  # gain_first: exposure parked at gain_first_exposure_us; it moves only when gain is at a limit
            t_fix = p.gain_first_exposure_us
            g_needed = (ln_p - math.log(t_fix)) * _DB_PER_LN
            if g_needed > g_hi:
                t = float(np.clip(math.exp(ln_p - g_hi / _DB_PER_LN), t_fix, t_hi))
            elif g_needed < g_lo:
                t = float(np.clip(math.exp(ln_p - g_lo / _DB_PER_LN), t_lo, t_fix))
            else:
                t = t_fix
        g = float(np.clip((ln_p - math.log(t)) * _DB_PER_LN, g_lo, g_hi))
        return Settings(g, t).clamped()
