"""The oracle controller (simulator only; docs/controllers.md, The oracle): the greedy one-step upper bound.

At frame t it renders frame t+1 for every candidate (gain, exposure) from the same pose, with the same sensor noise
the camera will really get at t+1 (`sensor_rng(seed, camera, t+1)`), and scores each candidate image against frame
t: inlier matches (ties: more features, then lower gain) and feature count. No causal controller can know frame
t+1's scene; the oracle is still not a global optimum (greedy, one step, discrete grid).

Objective (`objective`):
- "match" — issue 7's rule: command the candidate with the most inlier matches with frame t. Measured in the
  simulator (validation passage + test exit windows, 320×240) this rule is path-dependent: continuity with an
  already badly exposed frame t outscores a jump to a good exposure (an overexposed frame t matches an equally
  overexposed t+1 best), so it locks into overexposure and lost VO track on both windows (dynamic ORB minimum NFM
  12 / 11 vs AG+AE 87 / 132) — no upper bound.
- "hybrid" (default; docs/controllers.md and the network's own training target M_hybrid, with perfect one-step
  knowledge): the average of the match-best and the feature-best candidate's settings (`hybrid_feat_weight` on the
  latter, in the linearly scaled ranges the labels use). The feature term pulls it out of such lock-ins while the
  match term keeps transitions gradual. Same windows: tracked both, dynamic ORB minimum 89 / 177, median 464 / 329
  (AG+AE 192 / 250). The hybrid setting is usually off the grid, so frame t+1 is rendered once more at it.

Candidates (config `controllers.oracle`): an exposure-first ladder — every exposure of `exposures_us` at 0 dB, then
every gain of `gains_db` at the longest exposure — as AG+AE itself spends exposure before gain. Default: 1 EV steps
over the whole range (9 exposures 30 ms … 117 µs, gains 6 … 30 dB at 30 ms): 14 candidates, 9 renders per frame.

Cost: rendering dominates. Candidates that share an exposure share one render (`CachedScene`, which the closed loop
also reads, so a chosen grid candidate's render is reused for the real frame t+1), and matching runs at
`match_width` (the ORB front end's working size is scaled down to it). `timings_ms` records each decision's time.
With `candidate_render: match` the candidates are rendered at the matching size itself (the camera's size divided
by the largest integer k with width/k >= match_width; 640x480 -> 320x240 for the default 320): one ray per pixel of
the image the matcher reads instead of four, each pixel replicated k x k back to the camera's size so the sensor
applies its own per-pixel noise, fixed pattern and clipping exactly as at full size. The frame the loop then
delivers at the chosen setting is always rendered at full size; no other run ever sees a coarse render.
docs/scale_out.md (The oracle's candidates at the matching size) has what it changes and costs.

The loop does not pass the frame index, so the oracle counts frames from `first_frame` (the first frame the loop
runs, warm-up included) and advances by one per `update` after `reset`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.config_reader import param, read_config
from expoctl.controllers.base import Controller, Settings
from expoctl.controllers.registry import ControllerContext, register_controller

_DEFAULT_EXPOSURES_US = tuple(round(EXPOSURE_US_MAX / 2.0**k, 1) for k in range(9))  # 30000 … 117.2 µs, 1 EV apart
_DEFAULT_GAINS_DB = (6.0, 12.0, 18.0, 24.0, 30.0)  # 6.02 dB ≈ 1 EV of signal
OBJECTIVES = ("match", "hybrid")
CANDIDATE_RENDERS = ("full", "match")


@dataclass(frozen=True)
class OracleParams:
    """Config `controllers.oracle`."""

    exposures_us: tuple[float, ...] = param(_DEFAULT_EXPOSURES_US, min=EXPOSURE_US_MIN, max=EXPOSURE_US_MAX, unit="µs")
    gains_db: tuple[float, ...] = param(_DEFAULT_GAINS_DB, min=GAIN_DB_MIN, max=GAIN_DB_MAX, unit="dB", empty=True)
    match_width: int = param(320, min=32)  # ORB working width for the candidate matching (height keeps the aspect)
    match_nfeatures: int = param(1000, min=10)
    warmup_frames: int = param(10, min=0)  # evaluate runs the oracle with min(this, evaluate.warmup_frames) warm-up
    objective: str = param("hybrid", choices=OBJECTIVES)  # hybrid (docs/controllers.md) | match (issue 7's rule)
    hybrid_feat_weight: float = param(0.5, min=0.0, max=1.0)  # hybrid: weight of the feature-best candidate's settings
    # full: each candidate rendered at the camera's size (then downscaled to match_width for matching); match: at
    # the largest integer fraction of it not below match_width, pixels replicated back to the camera's size so the
    # sensor adds the very noise it adds at full size (module docstring, Cost)
    candidate_render: str = param("full", choices=CANDIDATE_RENDERS)

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "controllers.oracle", problems=None) -> "OracleParams":
        return read_config(cls, d, key, problems)

    def candidates(self) -> list[Settings]:
        """The ladder: each exposure at 0 dB, then each gain at the longest exposure (duplicates dropped)."""
        longest = max(self.exposures_us)
        out = [Settings(GAIN_DB_MIN, e) for e in self.exposures_us]
        out += [Settings(g, longest) for g in self.gains_db if g > GAIN_DB_MIN]
        seen, uniq = set(), []
        for s in out:
            if (s.gain_db, s.exposure_us) not in seen:
                seen.add((s.gain_db, s.exposure_us))
                uniq.append(s)
        return uniq


class CachedScene:
    """A `Scene` wrapper that remembers the luminance of the latest frame(s) per (frame, exposure, camera).

    The oracle renders frame t+1 at every candidate exposure; the closed loop then asks for frame t+1 at the chosen
    one, which is served from here instead of being rendered again. Only the `keep_frames` newest frames stay."""

    def __init__(self, scene, keep_frames: int = 2):
        self.scene = scene
        self.keep_frames = keep_frames
        self._cache: dict[tuple[int, float, int, int], np.ndarray] = {}
        self.n_renders = 0

    def luminance(self, frame_index: int, exposure_us: float, camera: int) -> np.ndarray:
        return self._cached(frame_index, exposure_us, camera, 1)

    @property
    def has_coarse(self) -> bool:
        """Whether the wrapped scene renders at a fraction of its size (`luminance_coarse`, a RouteScene does)."""
        return hasattr(self.scene, "luminance_coarse")

    def luminance_coarse(self, frame_index: int, exposure_us: float, camera: int, factor: int) -> np.ndarray:
        """The wrapped scene's render at 1/factor of its size, cached apart from the full-size ones (a run that asks
        for the full frame never gets a coarse one)."""
        return self._cached(frame_index, exposure_us, camera, int(factor))

    def _cached(self, frame_index: int, exposure_us: float, camera: int, factor: int) -> np.ndarray:
        key = (int(frame_index), float(exposure_us), int(camera), factor)
        if key not in self._cache:
            stale = [k for k in self._cache if k[0] <= frame_index - self.keep_frames]
            for k in stale:
                del self._cache[k]
            self._cache[key] = (self.scene.luminance(frame_index, exposure_us, camera) if factor == 1 else
                                self.scene.luminance_coarse(frame_index, exposure_us, camera, factor))
            self.n_renders += 1
        return self._cache[key]

    def timestamp_ns(self, frame_index: int) -> int:
        return self.scene.timestamp_ns(frame_index)


class OracleController(Controller):
    """Greedy one-step oracle over a candidate grid (see module docstring)."""

    name = "oracle"

    def __init__(self, scene, sensor, seed: int, n_frames: int, first_frame: int = 0,
                 params: OracleParams | None = None, camera: int = 1):
        from expoctl.features.orb import OrbFrontEnd

        self.scene = scene if isinstance(scene, CachedScene) else CachedScene(scene)
        self.sensor = sensor
        self.seed = int(seed)
        self.n_frames = int(n_frames)
        self.first_frame = int(first_frame)
        self.params = params or OracleParams()
        self.camera = int(camera)
        self._candidates = self.params.candidates()
        self._orb_params = {"match_nfeatures": self.params.match_nfeatures,
                            "count_nfeatures": self.params.match_nfeatures}
        self._frontend_cache: dict[tuple[int, int], OrbFrontEnd] = {}
        self._t = self.first_frame
        self.timings_ms: list[float] = []
        self.choices: list[tuple[int, Settings, int, int]] = []  # (t+1, settings, n_inliers, n_features)

    def _frontend(self, shape: tuple[int, int]):
        from expoctl.features.orb import OrbFrontEnd

        h, w = shape
        if (h, w) not in self._frontend_cache:
            mw = min(self.params.match_width, w)
            size = None if mw == w else (mw, max(32, int(round(h * mw / w))))
            self._frontend_cache[(h, w)] = OrbFrontEnd({**self._orb_params, "working_size": size})
        return self._frontend_cache[(h, w)]

    def _coarse_factor(self, width: int, height: int) -> int:
        """1, or with candidate_render "match" the largest k with width / k >= match_width that divides the image
        (and the scene can render at 1/k): candidates are then rendered at (width/k, height/k)."""
        if self.params.candidate_render != "match" or not self.scene.has_coarse:
            return 1
        k = width // self.params.match_width
        while k > 1 and (width % k or height % k):
            k -= 1
        return max(k, 1)

    def reset(self, initial: Settings) -> None:
        self._t = self.first_frame
        self.timings_ms.clear()
        self.choices.clear()

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        from expoctl.features.pipeline import rgb_to_grey
        from expoctl.sim.closed_loop import sensor_rng

        t0 = time.perf_counter()
        t = self._t
        self._t += 1
        nxt = t + 1
        if nxt >= self.n_frames:  # no frame t+1 to render: keep the settings
            return applied
        grey = rgb_to_grey(image)
        frontend = self._frontend(grey.shape)
        prev = frontend.extract(grey)
        best_key, best = None, applied
        feat_key, feat_best = None, applied
        factor = self._coarse_factor(image.shape[1], image.shape[0])
        replicated: dict[float, np.ndarray] = {}  # the gain rungs share the longest exposure: replicate it once
        for cand in self._candidates:
            if factor > 1:
                lum = replicated.get(cand.exposure_us)
                if lum is None:
                    lum = self.scene.luminance_coarse(nxt, cand.exposure_us, self.camera, factor)
                    lum = replicated[cand.exposure_us] = np.repeat(np.repeat(lum, factor, axis=0), factor, axis=1)
            else:
                lum = self.scene.luminance(nxt, cand.exposure_us, self.camera)
            img = self.sensor.capture(lum, cand.exposure_us, cand.gain_db, sensor_rng(self.seed, self.camera, nxt))
            cur = frontend.extract(rgb_to_grey(img))
            n_inl = int(frontend.match(prev, cur, nxt)[1])
            n_feat = int(frontend.n_features(cur))
            key = (n_inl, n_feat, -cand.gain_db)
            if best_key is None or key > best_key:
                best_key, best = key, cand
            fkey = (n_feat, n_inl, -cand.gain_db)
            if feat_key is None or fkey > feat_key:
                feat_key, feat_best = fkey, cand
        if self.params.objective == "hybrid":
            best = hybrid_settings(feat_best, best, self.params.hybrid_feat_weight)
        self.choices.append((nxt, best, best_key[0], best_key[1]))
        self.timings_ms.append((time.perf_counter() - t0) * 1e3)
        return best


def hybrid_settings(feat: Settings, match: Settings, feat_weight: float) -> Settings:
    """w·feat + (1 − w)·match in the network's linearly scaled gain/exposure (the labels' M_hybrid average)."""
    from expoctl.camera.ranges import exposure_to_norm, gain_to_norm, norm_to_exposure, norm_to_gain

    g = feat_weight * gain_to_norm(feat.gain_db) + (1 - feat_weight) * gain_to_norm(match.gain_db)
    e = feat_weight * exposure_to_norm(feat.exposure_us) + (1 - feat_weight) * exposure_to_norm(match.exposure_us)
    return Settings(float(norm_to_gain(g)), float(norm_to_exposure(e)))


def make_oracle(params: dict | OracleParams | None, scene, sensor, seed: int, n_frames: int, first_frame: int = 0,
                camera: int = 1) -> OracleController:
    """The oracle from its config (or config section) plus the simulator objects it needs."""
    config = params if isinstance(params, OracleParams) else OracleParams.from_dict(params)
    return OracleController(scene, sensor, seed, n_frames, first_frame, config, camera)


def _build_oracle(config: OracleParams, context: ControllerContext) -> Controller:
    """Registry factory: the oracle over the context's scene, sensor and frames (evaluate builds it so)."""
    return make_oracle(config, context.scene, context.sensor, context.seed, context.n_frames, context.first_frame)


# registered here, beside the oracle: the controller registry imports this module with its own (plugins.Registry)
register_controller("oracle", config=OracleParams, factory=_build_oracle, needs=("scene",), label="Greedy oracle",
                    colour="#2ca02c", rank=70)(OracleController)
