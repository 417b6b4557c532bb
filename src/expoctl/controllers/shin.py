"""Shin et al. 2019 noise-aware exposure control, run online (docs/controllers.md, Shin et al. 2019).

Metric: `metrics.shin_score` = α·K_g·G + (1−α)·E − β·N with the MATLAB constants (α 0.4, K_g 2, β 0.4, λ 1e3,
δ 0.06, 10×10 grid). Search: Nelder–Mead (reflection 1, expansion 2, contraction 0.5, shrink 0.5, stop when the f
spread < 1e-5 or after 50 evaluations) minimising f = −score.

Online, every function evaluation costs one captured frame: the controller commands a simplex vertex, the camera
applies it at t+1, and the image that comes back at t+1 (captured with exactly those settings) is scored and fed to
the search. The search is a generator that yields points and receives their f.

Deviations from the MATLAB demo (Test_nelder_mead_AE.m / nelder_mead_AE.m), all because frames are real and costly:
- Coordinates are (gain in stops, log2 exposure): both axes in EV, so the simplex is well scaled (MATLAB mixes dB
  and µs) and a gain of 0 dB does not collapse it. Initial vertices: x0 + s·e_gain and x0 + s·e_exposure with
  s = log2(1 + h), MATLAB's h = −(1/1.7)(I/255) if I ≥ 128 else 1.7(1 − I/255) (I = mean grey); |s| ≥ 0.25 EV; a
  vertex that would leave the valid box is mirrored to the other side of x0. Points are clipped into the box.
- No grid snapping (the demo looks values up in a pre-captured grid); the current frame scores x0 for free; a
  shrink does not re-evaluate the best vertex (MATLAB re-scores it, costing a frame).
- Restart policy (the objective drifts while the simplex searches, and saturated frames make it flat):
  * after convergence the controller holds the best point and keeps scoring every frame; it restarts from the
    current point when the median score of the last `hold_window` held frames differs from the median of the
    first `hold_window` by more than max(restart_abs_drift, restart_rel_drift·|reference|) (medians, because
    sensor noise alone moves a single frame's score by several per cent at high gain), or at once when the held
    image is badly exposed (mean grey < dark_mean or > bright_mean);
  * searching or holding, it restarts at once when the scene brightness estimate (linear mean of unclipped pixels
    divided by the exposure product) has moved by more than restart_scene_ev since the search began;
  * a search restarts from the frame in hand when `max_mismatched_frames` frames in a row were not captured at
    the commanded vertex (the camera did not apply it);
  * a restart from a badly exposed frame first moves x0 along exposure by MATLAB's h step (a mean-intensity
    pre-correction; otherwise a fully saturated simplex is flat and the search would stall where it is).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import math
from collections.abc import Generator

import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.controllers.base import Controller, Settings
from expoctl.controllers.registry import register_controller
from expoctl.camera.response import uint8_to_linear
from expoctl.controllers.metrics import luma_uint8, shin_score
from expoctl.config_reader import Section, read_config

DB_PER_STOP = 20.0 * math.log10(2.0)
_BOX_LO = np.array([GAIN_DB_MIN / DB_PER_STOP, math.log2(EXPOSURE_US_MIN)])
_BOX_HI = np.array([GAIN_DB_MAX / DB_PER_STOP, math.log2(EXPOSURE_US_MAX)])

@dataclass(frozen=True)
class ShinConfig:
    """`controllers.shin`."""

    alpha: float = 0.4
    k_g: float = 2.0
    beta: float = 0.4
    lam: float = 1e3
    delta: float = 0.06
    n_cells: int = 10
    reflection: float = 1.0
    expansion: float = 2.0
    contraction: float = 0.5
    shrink: float = 0.5
    tolerance: float = 1e-5
    max_evaluations: int = 50
    min_initial_step_ev: float = 0.25
    restart_abs_drift: float = 0.05
    restart_rel_drift: float = 0.1
    hold_window: int = 3  # frames per median in the hold-phase drift test
    restart_scene_ev: float = 1.5
    dark_mean: float = 15.0
    bright_mean: float = 240.0
    max_mismatched_frames: int = 3  # frames not taken at the commanded vertex before the search restarts from them

    def check(self, r: Section) -> None:
        """Bounds and the rules between keys (read_config runs it once every key has the right type)."""
        checks = [
            (0.0 <= self.alpha <= 1.0, "alpha", "must be in [0, 1]"),
            (self.k_g >= 0 and self.beta >= 0, "beta", "k_g and beta must be >= 0"),
            (self.lam > 0, "lam", "must be > 0"),
            (0.0 <= self.delta < 1.0, "delta", "must be in [0, 1)"),
            (self.n_cells >= 2, "n_cells", "must be >= 2"),
            (self.reflection > 0, "reflection", "must be > 0"),
            (self.expansion > max(1.0, self.reflection), "expansion", "must be > max(1, reflection)"),
            (0 < self.contraction < 1, "contraction", "must be in (0, 1)"),
            (0 < self.shrink < 1, "shrink", "must be in (0, 1)"),
            (self.tolerance >= 0, "tolerance", "must be >= 0"),
            (self.max_evaluations >= 3, "max_evaluations", "must be >= 3 (one simplex)"),
            (self.min_initial_step_ev > 0, "min_initial_step_ev", "must be > 0"),
            (self.restart_abs_drift >= 0 and self.restart_rel_drift >= 0, "restart_rel_drift", "must be >= 0"),
            (self.restart_scene_ev > 0, "restart_scene_ev", "must be > 0"),
            (0 <= self.dark_mean < self.bright_mean <= 255, "bright_mean", "need 0 <= dark_mean < bright_mean <= 255"),
            (self.max_mismatched_frames >= 1, "max_mismatched_frames", "must be >= 1"),
            (self.hold_window >= 1, "hold_window", "must be >= 1"),
        ]
        for ok, key, problem in checks:
            if not ok:
                r.problem(key, problem)


def to_point(s: Settings) -> np.ndarray:
    return np.array([s.gain_db / DB_PER_STOP, math.log2(s.exposure_us)])


def to_settings(x: np.ndarray) -> Settings:
    return Settings(float(x[0]) * DB_PER_STOP, float(2.0 ** x[1])).clamped()


def clip_box(x: np.ndarray) -> np.ndarray:
    return np.clip(x, _BOX_LO, _BOX_HI)


def matlab_h(mean_grey: float) -> float:
    """Shin's initial-simplex step factor from the mean intensity I (0–255)."""
    i = mean_grey / 255.0
    return -(1.0 / 1.7) * i if mean_grey >= 128 else 1.7 * (1.0 - i)


def nelder_mead(
    simplex: np.ndarray, rho: float, xi: float, gam: float, sig: float, tol: float, max_evals: int
) -> Generator[np.ndarray, float, tuple[np.ndarray, float]]:
    """Nelder–Mead minimiser as a coroutine: yields a point, receives its f via send(); returns (best x, best f).
    Follows the classic scheme (Nelder & Mead 1965) with the coefficients of Shin's MATLAB."""
    x = np.array([clip_box(v) for v in simplex], dtype=np.float64)
    n = x.shape[1]
    f = np.empty(n + 1)
    for i in range(n + 1):
        f[i] = yield x[i]
    n_evals = n + 1
    order = np.argsort(f, kind="stable")
    x, f = x[order], f[order]
    while f[-1] - f[0] >= tol and n_evals < max_evals:
        centroid = x[:n].mean(axis=0)
        x_r = clip_box((1 + rho) * centroid - rho * x[n])
        f_r = yield x_r
        n_evals += 1
        if f[0] <= f_r <= f[n - 1]:
            x[n], f[n] = x_r, f_r
        elif f_r < f[0]:
            x_e = clip_box((1 + rho * xi) * centroid - rho * xi * x[n])
            f_e = yield x_e
            n_evals += 1
            x[n], f[n] = (x_e, f_e) if f_e < f_r else (x_r, f_r)
        else:
            if f_r < f[n]:  # outside contraction
                x_c = clip_box((1 + rho * gam) * centroid - rho * gam * x[n])
                accept_limit = f_r
            else:  # inside contraction
                x_c = clip_box((1 - gam) * centroid + gam * x[n])
                accept_limit = f[n]
            f_c = yield x_c
            n_evals += 1
            if f_c <= accept_limit:
                x[n], f[n] = x_c, f_c
            else:  # shrink towards the best vertex (its f is kept: no extra frame)
                for i in range(1, n + 1):
                    x[i] = clip_box(sig * x[i] + (1 - sig) * x[0])
                    f[i] = yield x[i]
                    n_evals += 1
        order = np.argsort(f, kind="stable")
        x, f = x[order], f[order]
    return x[0].copy(), float(f[0])


@register_controller("shin", config=ShinConfig, label="Shin", colour="#9467bd", rank=20)
class ShinController(Controller):
    name = "shin"

    def __init__(self, config: ShinConfig | dict | None = None):
        """`config`: the typed config, or its section as a mapping (read and checked here)."""
        if not isinstance(config, ShinConfig):
            config = read_config(ShinConfig, config, "controllers.shin")
        p = self.config = config
        self.reset(Settings(0.0, 5000.0))

    # ------------------------------------------------------------------------------------------------ public API
    def reset(self, initial: Settings) -> None:
        self._search: Generator | None = None
        self._pending: np.ndarray | None = None  # point we commanded and whose image we wait for
        self._hold: np.ndarray | None = None
        self._hold_scores: list[float] = []  # scores of the frames captured at the held point
        self._search_scene_ev: float | None = None
        self._command = initial.clamped()
        self.n_restarts = -1  # the first search is not a restart

    def score(self, image: np.ndarray) -> float:
        p = self.config
        return shin_score(image, p.alpha, p.k_g, p.beta, p.lam, p.delta, p.n_cells)[0]

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        applied = applied.clamped()
        x_now = to_point(applied)
        score = self.score(image)
        mean = float(luma_uint8(image).mean())
        scene_ev = self._scene_ev(image, applied)
        self._last_mean, self._last_scene_ev = mean, scene_ev
        if self._search is None and self._hold is None:
            self._start_search(x_now, mean, scene_ev)
        elif self._scene_changed(scene_ev) or (self._hold is not None and self._hold_drifted(score, mean)):
            self._start_search(x_now, mean, scene_ev)
        if self._search is not None:
            self._advance(x_now, -score)
            if self._search is None and self._badly_exposed(mean):
                # converged on a flat (saturated/black) simplex: move on from the frame in hand right away
                self._start_search(x_now, mean, scene_ev)
                self._advance(x_now, -score)
        return self._command

    # ------------------------------------------------------------------------------------------------ internals
    def _scene_changed(self, scene_ev: float | None) -> bool:
        return (
            scene_ev is not None
            and self._search_scene_ev is not None
            and abs(scene_ev - self._search_scene_ev) > self.config.restart_scene_ev
        )

    def _hold_drifted(self, score: float, mean: float) -> bool:
        if self._badly_exposed(mean):
            return True
        self._hold_scores.append(score)
        n = self.config.hold_window
        if len(self._hold_scores) < 2 * n:
            return False
        reference = float(np.median(self._hold_scores[:n]))
        recent = float(np.median(self._hold_scores[-n:]))
        limit = max(self.config.restart_abs_drift, self.config.restart_rel_drift * abs(reference))
        return abs(recent - reference) > limit

    def _badly_exposed(self, mean: float) -> bool:
        return mean < self.config.dark_mean or mean > self.config.bright_mean

    @staticmethod
    def _scene_ev(image: np.ndarray, s: Settings) -> float | None:
        """log2 of (linear mean of unclipped pixels / exposure product): a brightness estimate of the scene that
        does not depend on the settings; None when fewer than 5 % of pixels are unclipped."""
        y = luma_uint8(image)
        ok = (y > 8) & (y < 247)
        if ok.mean() < 0.05:
            return None
        lin = float(uint8_to_linear(y[ok]).mean())  # default response: only ratios matter here
        return math.log2(lin) - math.log2(s.exposure_us) - s.gain_db / DB_PER_STOP

    def _start_search(self, x_now: np.ndarray, mean: float, scene_ev: float | None) -> None:
        p = self.config
        self.n_restarts += 1
        h = matlab_h(mean)
        step = math.log2(1.0 + h)
        if abs(step) < p.min_initial_step_ev:
            step = math.copysign(p.min_initial_step_ev, step if step != 0 else 1.0)
        x0 = x_now.copy()
        if self._badly_exposed(mean):  # pre-correct so a flat (saturated/black) simplex can move:
            x0 = clip_box(x0 + np.array([0.0, step]))  # along exposure first,
            x0 = clip_box(x0 + np.array([step - (x0[1] - x_now[1]), 0.0]))  # gain takes what exposure could not
        vertices = [x0]
        for axis in range(2):
            v = x0.copy()
            v[axis] += step
            if v[axis] < _BOX_LO[axis] or v[axis] > _BOX_HI[axis]:
                v[axis] = x0[axis] - step  # mirror: keeps the simplex non-degenerate at a range limit
            vertices.append(clip_box(v))
        self._mismatches = 0
        self._search = nelder_mead(
            np.array(vertices), p.reflection, p.expansion, p.contraction, p.shrink, p.tolerance,
            p.max_evaluations,
        )
        self._hold = None
        self._pending = self._search.send(None)
        self._search_scene_ev = scene_ev

    def _advance(self, x_now: np.ndarray, f_now: float) -> None:
        """Feed the frame in hand to the search if it was taken at the pending point; command the next point.
        If the camera keeps delivering frames at other settings (it did not apply ours), restart from them."""
        if not np.allclose(self._pending, x_now, atol=0.02):  # 0.02 EV: settings round-trip tolerance
            self._mismatches += 1
            if self._mismatches >= self.config.max_mismatched_frames:
                self._start_search(x_now, self._last_mean, self._last_scene_ev)
        for _ in range(8):  # a new point equal to the one in hand is scored with the same frame
            if not np.allclose(self._pending, x_now, atol=0.02):
                break
            self._mismatches = 0
            try:
                self._pending = self._search.send(f_now)
            except StopIteration as done:
                best_x, _ = done.value
                self._search, self._pending = None, None
                self._hold, self._hold_scores = best_x, []
                self._command = to_settings(best_x)
                return
        self._command = to_settings(self._pending)
