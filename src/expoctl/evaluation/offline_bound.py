"""The offline optimum over a candidate grid: what no controller restricted to that grid can beat (docs/evaluation.md,
The offline bound).

Public function (`expoctl bench` and evaluate call it; simulator only):

    offline_bound(scene, sensor, window: WindowFrames, seed: int, frontends: dict[str, FrontEnd], *,
                  candidates: Sequence[Settings] | None = None, sumlog: dict[str, SumLogParams] | None = None,
                  min_section_frames: int = 1, camera: int = 1,
                  kinds: Sequence[str] | None = ("static", "dynamic")) -> WindowBound

    scene, sensor: the window's (evaluate: `runner.window_sim(inputs, window)` .scene / .sensor); seed: the window's
    noise seed (`Window.seed`); frontends: {name: front end} as evaluate builds them; candidates: the grid (default
    `OracleParams().candidates()`, the oracle's 14-rung ladder); sumlog: also bound the SumLog variants;
    min_section_frames: evaluate's rule for which sections count. `WindowBound.to_dict()` is its JSON form.

Full knowledge of the window: at every recorded frame t and for every candidate c it captures the image a
controller commanding c for frame t really gets (the same scene luminance, the same sensor, the noise of
`sensor_rng(seed, camera, t)`, as `closed_loop._capture`; candidates sharing an exposure share one render), extracts
each front end's features of every (t, c) once and matches every pair: N_t[i, j] = inliers(image(t−1, i),
image(t, j)) with `pair_seed(sequence, t, variant)`, exactly `run.PairMatches`' rule. The built-in front ends'
`match` is a pure function of (features, features, seed) (evaluate makes fresh front ends per run only because a
plugin's might keep state; none of the built-ins does), so a grid-restricted controller's evaluate NFM at frame t is
the matrix entry of its path, N_t[c(t−1), c(t)] (tests/evaluation/test_offline_bound.py asserts it on every frame). A
front end whose matcher did keep state would break that equality, and the bound would bound only the matrix.

Why it bounds: offline, any sequence of grid settings is feasible (a schedule commanding c(t+1) at frame t is a
controller, and the one frame of latency costs nothing when the sequence is known in advance), so a section's
optimum over all grid paths is at least what any controller restricted to the grid scores there. Per section
(maximal runs of one label, the pair (t−1, t) counted in frame t's section, sections with fewer than
`min_section_frames` pairs left out: aggregate.section_stats' rule) and per front-end variant:
- `min`: a bottleneck path (maximises the minimum NFM over the section's pairs), exact;
- `sum`: a Viterbi path (maximises the sum, hence the mean), exact;
- `median`: with n pairs, the median is the ((n+1)/2)-th largest (n odd) or the mean of the (n/2)-th and (n/2+1)-th
  largest (n even); the largest attainable k-th largest value is exact (a threshold search over a count DP), so the
  bound is exact for odd n and, for even n, the mean of the two separately maximised order statistics: an upper
  bound that one path need not attain (`median_attained`: the best median of the paths found; equal when exact).
Each section is optimised on its own: its paths start at the frame before its first pair, which the previous
section's paths may set differently, so the section values are attained one section at a time, not by one path.

It bounds nothing off the grid: a controller commanding settings between the rungs (or gain below the longest
exposure) can score more. The report prints the grid beside the number for that reason.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from expoctl.evaluation.config import OfflineBoundParams  # noqa: F401 (re-exported: the bound's config)
from expoctl.controllers.base import Controller, Settings

#: the statistics a section's bound holds, per front-end variant
STATS = ("min", "sum", "median")


# --------------------------------------------------------------------------------------------------------- config


# the config group `evaluate.offline_bound` lives with evaluate's other config (expoctl.evaluation.config)


def grid_label(candidates: Sequence[Settings]) -> str:
    """The grid in words, e.g. "14-candidate ladder, 1 EV": its size and EV resolution (the median step between
    neighbouring candidates in total EV, exposure plus gain)."""
    ev = np.sort([total_ev(c) for c in candidates])
    steps = np.diff(ev)
    res = float(np.median(steps)) if len(steps) else 0.0
    return f"{len(candidates)}-candidate ladder, {res:.3g} EV"


def total_ev(s: Settings) -> float:
    """The signal a setting collects in EV (log2): exposure plus gain (6.02 dB of gain is one EV of signal)."""
    return math.log2(s.exposure_us) + s.gain_db / (20.0 * math.log10(2.0))


# ------------------------------------------------------------------------------------------------ pairwise NFM


def pair_matrices(scene, sensor, window, seed: int, frontends: dict[str, Any], candidates: Sequence[Settings],
                  sumlog: dict | None = None, frames: Sequence[int] | None = None, camera: int = 1,
                  timings: dict[str, float] | None = None) -> dict[str, np.ndarray]:
    """{variant: (n, K, K) float array}: entry [k, i, j] = inliers between window frame k−1 under candidate i and frame
    k under candidate j (NaN where not computed: k = 0 and frames outside `frames`, the window frames k whose pair is
    needed; default all k >= 1). Variants in `run.variants` order (the SumLog ones only with `sumlog`)."""
    from expoctl.evaluation.run import pair_seed, variants
    from expoctl.features.pipeline import rgb_to_grey
    from expoctl.features.sumlog import sumlog_uint8
    from expoctl.sim.closed_loop import sensor_rng

    n, K = len(window.frames), len(candidates)
    names = variants(frontends) if sumlog is not None else tuple(frontends)
    out = {v: np.full((n, K, K), np.nan) for v in names}
    wanted = set(range(1, n) if frames is None else frames)
    extract = {k for k in range(n) if k in wanted or k + 1 in wanted}  # a pair needs both frames' features
    laps = timings if timings is not None else {}
    prev: dict[str, list] | None = None
    for k in range(n):
        if k not in extract:
            prev = None
            continue
        t = window.frames.start + k
        t0 = time.perf_counter()
        lum: dict[float, np.ndarray] = {}
        images = []
        for c in candidates:
            if c.exposure_us not in lum:  # the ladder's gain rungs share the longest exposure: one render
                lum[c.exposure_us] = scene.luminance(t, c.exposure_us, camera)
            images.append(sensor.capture(lum[c.exposure_us], c.exposure_us, c.gain_db, sensor_rng(seed, camera, t)))
        t1 = time.perf_counter()
        cur: dict[str, list] = {}
        for name, fe in frontends.items():
            greys = [rgb_to_grey(img) for img in images]
            cur[name] = [fe.extract(g) for g in greys]
            if sumlog is not None:
                cur[f"{name}_sumlog"] = [fe.extract(sumlog_uint8(img, sumlog[name])) for img in images]
        t2 = time.perf_counter()
        if k in wanted and prev is not None:
            for v in names:
                fe = frontends[v[:-len("_sumlog")] if v.endswith("_sumlog") else v]
                s = pair_seed(window.sequence, k, v)
                m = out[v][k]
                for i, a in enumerate(prev[v]):
                    for j, b in enumerate(cur[v]):
                        m[i, j] = float(fe.match(a, b, s)[1])
        t3 = time.perf_counter()
        for stage, dt in (("render_capture", t1 - t0), ("extract", t2 - t1), ("match", t3 - t2)):
            laps[stage] = laps.get(stage, 0.0) + dt
        prev = cur
    return out


# ------------------------------------------------------------------------------------------ dynamic programmes


def best_path(weights: np.ndarray, combine: str) -> tuple[float, list[int]]:
    """The best path through a trellis: `weights` (P, K, K), weights[p, i, j] the edge from state i at node p to
    state j at node p+1; returns (value, states of the P+1 nodes). combine "min": maximise the minimum edge
    (bottleneck); "sum": maximise the sum (Viterbi). Ties go to the lowest state index (deterministic)."""
    P, K, _ = weights.shape
    if P == 0:
        raise ValueError("a path needs at least one edge")
    score = np.full(K, np.inf if combine == "min" else 0.0)
    back = np.zeros((P, K), dtype=np.int64)
    for p in range(P):
        cand = (np.minimum(score[:, None], weights[p]) if combine == "min" else score[:, None] + weights[p])
        back[p] = np.argmax(cand, axis=0)  # first maximum: the lowest predecessor index
        score = cand[back[p], np.arange(K)]
    last = int(np.argmax(score))
    path = [last]
    for p in range(P - 1, -1, -1):
        path.append(int(back[p, path[-1]]))
    return float(score[last]), path[::-1]


def path_values(weights: np.ndarray, path: Sequence[int]) -> np.ndarray:
    """The edge weights a path collects (P values)."""
    return np.array([weights[p, path[p], path[p + 1]] for p in range(len(weights))], dtype=float)


def kth_largest_bound(weights: np.ndarray, k: int) -> tuple[float, list[int]]:
    """The largest value v such that some path has at least `k` edges >= v (the best attainable k-th largest edge),
    and such a path: a binary search over the distinct weights of a count DP (Viterbi on 1[w >= v])."""
    P = len(weights)
    if not 1 <= k <= P:
        raise ValueError(f"k must be in 1..{P}, got {k}")
    values = np.unique(weights)
    lo, hi = 0, len(values) - 1  # values[lo] is always feasible (every edge >= the smallest weight)
    best = best_path((weights >= values[0]).astype(float), "sum")[1]
    while lo < hi:
        mid = (lo + hi + 1) // 2
        count, path = best_path((weights >= values[mid]).astype(float), "sum")
        if count >= k:
            lo, best = mid, path
        else:
            hi = mid - 1
    return float(values[lo]), best


def section_bound(weights: np.ndarray) -> dict[str, Any]:
    """min / sum / median bounds of one section's trellis (see the module docstring), each with its path."""
    P = len(weights)
    vmin, pmin = best_path(weights, "min")
    vsum, psum = best_path(weights, "sum")
    if P % 2:
        vmed, pmed = kth_largest_bound(weights, (P + 1) // 2)
        med = {"value": vmed, "path": pmed, "exact": True, "attained": vmed}
    else:
        hi, phi = kth_largest_bound(weights, P // 2)
        lo, plo = kth_largest_bound(weights, P // 2 + 1)
        tried = [phi, plo, pmin, psum]
        meds = [float(np.median(path_values(weights, p))) for p in tried]
        i = int(np.argmax(meds))
        bound = (hi + lo) / 2.0
        med = {"value": bound, "path": tried[i], "exact": meds[i] == bound, "attained": meds[i]}
    return {"min": {"value": vmin, "path": pmin},
            "sum": {"value": vsum, "mean": vsum / P, "path": psum},
            "median": med}


# ------------------------------------------------------------------------------------------------ per window


def window_sections(labels: Sequence[str], min_section_frames: int = 1) -> list[dict]:
    """The window's sections as evaluate counts them (aggregate.add_section_ids / section_stats): maximal runs of one
    label; the NFM of frame k (pair k−1, k) belongs to frame k's section and frame 0 has none; sections with fewer
    than `min_section_frames` pairs are left out. Each: section_id, kind, first_frame, last_frame, pairs (frames)."""
    out, start = [], 0
    for k in range(1, len(labels) + 1):
        if k == len(labels) or labels[k] != labels[start]:
            pairs = [f for f in range(start, k) if f >= 1]
            out.append({"section_id": len(out), "kind": str(labels[start]), "first_frame": start,
                        "last_frame": k - 1, "pairs": pairs})
            start = k
    return [s for s in out if len(s["pairs"]) >= min_section_frames]


@dataclass
class WindowBound:
    """One window's bound: the grid, and per counted section and variant its min / sum / median bounds and paths
    (a path: candidate indices of window frames `path_first_frame` … last_frame)."""

    sequence: str
    candidates: list[Settings]
    sections: list[dict]
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    n_frames: int = 0

    def path_settings(self, section_id: int, variant: str, stat: str) -> dict[int, Settings]:
        """{window frame: Settings} of one section's optimal path."""
        s = next(s for s in self.sections if s["section_id"] == section_id)
        path = s["bounds"][variant][stat]["path"]
        return {s["path_first_frame"] + i: self.candidates[c] for i, c in enumerate(path)}

    def to_dict(self) -> dict:
        return {"sequence": self.sequence, "n_frames": self.n_frames, "seconds": self.seconds,
                "timings_s": dict(self.timings),
                "candidates": [{"gain_db": c.gain_db, "exposure_us": c.exposure_us} for c in self.candidates],
                "sections": self.sections}


def offline_bound(scene, sensor, window, seed: int, frontends: dict[str, Any], *,
                  candidates: Sequence[Settings] | None = None, sumlog: dict | None = None,
                  min_section_frames: int = 1, camera: int = 1,
                  kinds: Sequence[str] | None = ("static", "dynamic")) -> WindowBound:
    """The offline optimum of one window over a candidate grid (module docstring: signature, what it bounds).
    `kinds`: the section labels bounded (default metrics.json's; None: every label, `interior` too)."""
    from expoctl.sim.oracle import OracleParams

    t0 = time.perf_counter()
    candidates = list(OracleParams().candidates() if candidates is None else candidates)
    if not candidates:
        raise ValueError("offline_bound: the candidate grid is empty")
    # only the kinds metrics.json reports: an interior section's K² matches per frame would buy no number
    sections = [s for s in window_sections(list(window.section), min_section_frames)
                if kinds is None or s["kind"] in kinds]
    needed = sorted({k for s in sections for k in s["pairs"]})
    timings: dict[str, float] = {}
    mats = pair_matrices(scene, sensor, window, seed, frontends, candidates, sumlog, needed, camera, timings)
    out = []
    for s in sections:
        a, b = s["pairs"][0], s["pairs"][-1]
        bounds = {v: section_bound(m[a:b + 1]) for v, m in mats.items()}
        out.append({"section_id": s["section_id"], "kind": s["kind"], "first_frame": s["first_frame"],
                    "last_frame": s["last_frame"], "n_pairs": len(s["pairs"]), "path_first_frame": a - 1,
                    "bounds": bounds})
    return WindowBound(window.sequence, candidates, out, time.perf_counter() - t0, timings, len(window.frames))


def aggregate_bounds(entries: Sequence[tuple[str, WindowBound]]) -> dict:
    """{route_split: {kind: {variant: {min_nfm, median_nfm, mean_nfm}}}}: the mean over sections of each section's
    bound, as metrics.json averages a controller's section statistics (so each number bounds the grid-restricted
    controllers' metrics.json number of the same key; mean_nfm bounds the mean over sections of the section means)."""
    acc: dict[str, dict[str, dict[str, dict[str, list[float]]]]] = {}
    for split, wb in entries:
        for s in wb.sections:
            for v, b in s["bounds"].items():
                cell = acc.setdefault(split, {}).setdefault(s["kind"], {}).setdefault(
                    v, {"min_nfm": [], "median_nfm": [], "mean_nfm": []})
                cell["min_nfm"].append(b["min"]["value"])
                cell["median_nfm"].append(b["median"]["value"])
                cell["mean_nfm"].append(b["sum"]["mean"])
    return {split: {kind: {v: {stat: float(np.mean(vals)) for stat, vals in cell.items()}
                           for v, cell in by_variant.items()} for kind, by_variant in sorted(by_kind.items())}
            for split, by_kind in acc.items()}


# --------------------------------------------------------------------------------------- controllers on a grid


def snap(settings: Settings, candidates: Sequence[Settings]) -> Settings:
    """The candidate nearest to `settings` in total EV (exposure plus gain: the brightness the controller asked for);
    ties: the nearer in (log2 exposure, gain in EV), then the first."""
    target, e = total_ev(settings), math.log2(settings.exposure_us)
    g = settings.gain_db / (20.0 * math.log10(2.0))

    def key(c: Settings):
        return (abs(total_ev(c) - target),
                math.hypot(math.log2(c.exposure_us) - e, c.gain_db / (20.0 * math.log10(2.0)) - g))

    return min(candidates, key=key)


class GridController(Controller):
    """A controller restricted to a grid: every command of `inner` snapped to the nearest candidate (`snap`); `inner`
    sees the snapped settings its frames were exposed with, as in any closed loop."""

    def __init__(self, inner: Controller, candidates: Sequence[Settings]):
        self.inner, self.candidates = inner, list(candidates)
        self.name = f"{getattr(inner, 'name', 'controller')}@grid"

    def reset(self, initial: Settings) -> None:
        self.inner.reset(initial)

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        return snap(self.inner.update(image, applied), self.candidates)


class ScheduleController(Controller):
    """Plays a schedule offline: at trajectory frame t it commands `schedule[t + 1]` (else keeps the settings), so
    frame t+1 is exposed with it (one frame of latency). Counts frames from `first_frame` (the first frame its loop
    runs, warm-up included), as the oracle does. Drives a bound's path (`WindowBound.path_settings`, shifted to
    trajectory frames) through evaluate's closed loop."""

    name = "schedule"

    def __init__(self, schedule: dict[int, Settings], first_frame: int):
        self.schedule, self.first_frame = dict(schedule), int(first_frame)
        self._t = self.first_frame

    def reset(self, initial: Settings) -> None:
        self._t = self.first_frame

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        t = self._t
        self._t += 1
        return self.schedule.get(t + 1, applied)


# ------------------------------------------------------------------------------------------ evaluate's windows


def _bound_job(job: tuple) -> dict:
    """One evaluate window's bound (a worker's job): (inputs, window, sumlog or None, candidates)."""
    from expoctl.evaluation.runner import window_sim
    from expoctl.features.pipeline import make_frontend

    inputs, w, sumlog, candidates = job
    ecfg, fcfg = inputs.evaluate, inputs.features
    sim = window_sim(inputs, w)
    frontends = {name: make_frontend(name, fcfg.config(name)) for name in ecfg.frontends}
    wb = offline_bound(sim.scene, sim.sensor, sim.frames, w.seed, frontends, candidates=candidates, sumlog=sumlog,
                       min_section_frames=ecfg.min_section_frames)
    return {"route_split": w.route_split, "bound": wb}


def evaluate_bounds(inputs, windows, sumlog: dict, parallel=None) -> dict:
    """reports/eval/offline_bound.json's content for evaluate's windows under `evaluate.offline_bound`: the grid, its
    label, the render size, per window its sections' bounds and paths, and the aggregate per split, kind, variant."""
    from expoctl.parallel import run_ordered

    cfg = inputs.evaluate.offline_bound
    candidates = cfg.candidates(inputs.controller_config("oracle"))
    jobs = [(inputs, w, sumlog if cfg.sumlog else None, candidates) for w in windows]
    results = [r for _job, r in run_ordered(_bound_job, jobs, None, parallel)]
    render = inputs.render
    return {
        "grid": {"label": grid_label(candidates),
                 "candidates": [{"gain_db": c.gain_db, "exposure_us": c.exposure_us} for c in candidates],
                 "source": "evaluate.offline_bound" if cfg.exposures_us is not None else "controllers.oracle"},
        "render_size": [render.width, render.height],
        "seconds": float(sum(r["bound"].seconds for r in results)),
        "metrics": aggregate_bounds([(r["route_split"], r["bound"]) for r in results]),
        "windows": [{"route_split": r["route_split"], **r["bound"].to_dict()} for r in results],
    }
