"""Closed-loop evaluation (the `evaluate` stage): every controller drives the simulated camera over the same windows.

Plan: for each route split (validation: world.cities.validation; test: world.cities.test), `n_traversals` traversals
(their own speed, sun, sky; seeds disjoint from `collect`'s), and in each the configured windows around tunnels
(`expoctl.evaluation.config`). One *run* = (window, controller); every controller of a window gets the same scene,
sensor parameters, fixed-pattern noise and per-frame noise seeds. Runs fan out over worker processes (`parallel.n_jobs`) or a
Ray cluster (`expoctl.parallel`); their results are gathered in plan order whatever the order they finish in.

SumLog: its parameters are tuned here, once per front end, before the fan-out, on sequential camera-1 pairs of the
training split (data/frames.parquet → the raw PNGs), over the grid `features.sumlog`, maximising total inlier matches
(`expoctl.features.sumlog.tune_sumlog`); the result is written to reports/eval/sumlog.json.

Outputs (`write_outputs`): reports/metrics.json (docs/evaluation.md), reports/eval/frames.parquet (per frame per run),
runs.parquet (per run: VO success, failed_at, ATE/RPE, timing), sections.parquet (per section statistics),
sumlog.json, thumbs/<run_id>.npz (frames around the portals, for the report's image strips).

Config read: `EvaluationInputs` (`expoctl.evaluation.inputs`), built once by the stage from `evaluate`, `seed`,
`sensor`, `world`, `rig`, `controllers`, `features`, `paths.model`, `paths.frames`; every run's worker gets it as is.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import pandas as pd

from expoctl.errors import ConfigError, InputError
from expoctl.evaluation.aggregate import add_section_ids, build_metrics, section_stats, validate_metrics
from expoctl.evaluation.config import ROUTE_SPLITS, SplitPlan
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.features.sumlog import SumLogParams
from expoctl.parallel import ParallelConfig, run_ordered


@dataclass(frozen=True)
class Window:
    """One stretch of one traversal, driven by every controller (trajectory frames [start, stop))."""

    route_split: str
    city: str | dict
    city_dir: str | None
    city_name: str
    traversal: int
    traversal_seed: int
    traversal_frames: int
    index: int  # window index within the traversal (see evaluation.config)
    label: str  # e.g. "tunnel 0 passage", "tunnel 1 exit"
    start: int
    stop: int
    seed: int  # sensor randomisation + noise seeds, shared by all controllers

    @property
    def sequence(self) -> str:
        return f"{self.route_split}-{self.city_name}-t{self.traversal:03d}-w{self.index:02d}"


@dataclass(frozen=True)
class RunJob:
    window: Window
    controller: str
    inputs: EvaluationInputs = field(repr=False)
    sumlog: dict[str, SumLogParams] = field(repr=False)
    model_path: str | None = None
    label: str = ""  # names the run instead of `controller` when several runs of a window share one (model selection)
    reference: str | None = None  # "module:attr" of a controller given by import path (`expoctl bench`)

    @property
    def run_id(self) -> str:
        return f"{self.window.sequence}-{self.label or self.controller}"


@dataclass
class EvaluationResult:
    frames: pd.DataFrame
    runs: pd.DataFrame
    sections: pd.DataFrame
    metrics: dict
    sumlog: dict[str, SumLogParams]
    thumbs: dict[str, dict[str, np.ndarray]]
    windows: list[Window]


# --------------------------------------------------------------------------------------------------------- planning


def plan_windows(inputs: EvaluationInputs, project_root: str | os.PathLike = ".") -> list[Window]:
    """Every window of the evaluation, in order (loads the cities' geometry, renders nothing)."""
    windows: list[Window] = []
    for split in ROUTE_SPLITS:
        if split in inputs.evaluate.splits:
            windows += split_windows(inputs, project_root, split)
    if not windows:
        raise ConfigError("evaluate.splits", "plans no window (give validation and/or test a plan)")
    return windows


def split_windows(inputs: EvaluationInputs, project_root: str | os.PathLike, split: str,
                  plan: SplitPlan | None = None) -> list[Window]:
    """evaluate's windows of route split `split` (validation | test), in plan order; `plan`: another plan of the same
    split (the environment plans one traversal at a time, expoctl.bench.env), the same windows where they overlap."""
    plan = inputs.evaluate.splits[split] if plan is None else plan
    return city_windows(inputs, project_root, split, split, plan, f"evaluate.splits.{split}", inputs.rig.fps,
                        inputs.evaluate.warmup_frames)


def city_windows(inputs: EvaluationInputs, project_root: str | os.PathLike, label: str, city_key: str, plan: SplitPlan,
                 plan_key: str, fps: float, warmup_frames: int) -> list[Window]:
    """The windows `plan` asks for on `world.cities.<city_key>`, labelled `label` (their route_split; it also seeds
    the traversals and noise, so two labels never share a window). `plan_key` is the config key errors name."""
    from expoctl.sim.collect import derive_seed
    from expoctl.world import load_city_cached
    from expoctl.world.cities import resolve_city_name

    base_seed = inputs.seed
    world = inputs.world.under(project_root)
    city_dir, cities = world.city_dir, world.cities
    if city_key not in cities:
        raise ConfigError(f"world.cities.{city_key}", f"missing: {plan_key} needs a city")
    spec = cities[city_key]
    name = resolve_city_name(spec, city_dir, f"world.cities.{city_key}")
    city = load_city_cached(spec, city_dir)
    if not city.tunnel_spans():
        raise ConfigError(f"world.cities.{city_key}", f"city {name!r} has no tunnel: nothing to drive windows around")
    tseed = derive_seed(base_seed, "evaluate-traversal", label)
    windows: list[Window] = []
    for k in range(plan.n_traversals):
        index = plan.first_traversal + k
        lap = city.traversal(index, None, fps, tseed)
        n = 2 * len(lap.timestamps_ns)  # two laps: every window fits whole somewhere
        traj = _trajectory_cached(city, index, n, fps, tseed)  # the one its windows' runs drive (window_sim)
        spans = _windows_of(traj.portal_times_s, plan, fps, n, warmup_frames, plan_key)
        chosen = range(len(spans)) if plan.windows is None else plan.windows
        for w in chosen:
            if w >= len(spans):
                raise ConfigError(f"{plan_key}.windows",
                                  f"window {w} does not exist: city {name!r} has {len(spans)} {plan.window} windows")
            wlabel, start, stop = spans[w]
            windows.append(Window(label, spec, city_dir, name, index, tseed, n, w, wlabel, start, stop,
                                  derive_seed(base_seed, "evaluate", label, name, index, w)))
    return windows


def _windows_of(portals: list, plan: SplitPlan, fps: float, n: int, warmup: int,
                plan_key: str | None = None) -> list[tuple[str, int, int]]:
    """(label, start, stop) per window in route order: the first occurrence with room for the warm-up before it."""
    tunnels = sorted({ti for _, ti, _ in portals})
    wanted: list[tuple[str, list]] = []
    for ti in tunnels:
        entries = [t for t, i, kind in portals if i == ti and kind == "entry"]
        exits = [t for t, i, kind in portals if i == ti and kind == "exit"]
        if plan.window == "passage":
            occ = [(te, min([tx for tx in exits if tx > te], default=math.inf)) for te in entries]
            wanted.append((f"tunnel {ti} passage", [(a, b) for a, b in occ if math.isfinite(b)]))
        else:
            wanted.append((f"tunnel {ti} entry", [(t, t) for t in entries]))
            wanted.append((f"tunnel {ti} exit", [(t, t) for t in exits]))
    out = []
    for label, occurrences in wanted:
        for a, b in sorted(occurrences):
            start = int(math.floor((a - plan.before_s) * fps))
            stop = int(math.ceil((b + plan.after_s) * fps)) + 1
            if start - warmup >= 0 and stop <= n:
                out.append((label, start, stop))
                break
        else:
            raise ConfigError(plan_key or f"evaluate.splits.{plan.name}", f"no room for the {label} window (before_s/after_s too "
                              "long for the route?)")
    return out


def window_annotations(traj, start: int, stop: int) -> tuple[list[str], np.ndarray, list[str]]:
    """Per frame of [start, stop): section label, signed time to the nearest portal crossing, that portal's kind."""
    times = np.asarray(traj.timestamps_ns[start:stop], dtype=np.float64) * 1e-9
    section = [str(s) for s in traj.frame_section[start:stop]]
    if not traj.portal_times_s:
        return section, np.full(len(times), np.nan), [""] * len(times)
    pt = np.array([p[0] for p in traj.portal_times_s])
    nearest = np.argmin(np.abs(times[:, None] - pt[None, :]), axis=1)
    return section, times - pt[nearest], [str(traj.portal_times_s[i][2]) for i in nearest]


# ------------------------------------------------------------------------------------------------------- SumLog


def tune_sumlog_params(inputs: EvaluationInputs, project_root: str | os.PathLike,
                       n_pairs: int) -> dict[str, SumLogParams]:
    """SumLog parameters per front end, tuned on sequential camera-1 training pairs (see module docstring)."""
    from expoctl.features.pipeline import iter_training_pairs_rgb, make_frontend
    from expoctl.features.sumlog import tune_sumlog

    fcfg = inputs.features
    frames_path = Path(project_root) / inputs.frames_path
    if not frames_path.is_file():
        raise InputError(f"{frames_path}: frames table missing (SumLog is tuned on the training frames); "
                         "run the ingest stage first")
    try:
        frames = pd.read_parquet(frames_path)
    except Exception as exc:  # pyarrow raises several types for a damaged file
        raise InputError(f"{frames_path}: not a readable Parquet file ({exc})") from None
    pairs = list(iter_training_pairs_rgb(frames, project_root, camera=1, max_pairs=n_pairs))
    if not pairs:
        raise InputError(f"{frames_path}: no sequential camera-1 pairs in the train split to tune SumLog on")
    grid = fcfg.sumlog
    out = {}
    for name in inputs.evaluate.frontends:
        fe = make_frontend(name, fcfg.config(name))
        out[name] = tune_sumlog(pairs, fe, grid.alphas, grid.betas, grid.rescale, seed=fcfg.seed)
    return out


# ------------------------------------------------------------------------------------------------------------- runs


def run_window(jobs: tuple[RunJob, ...]) -> list[tuple[list[dict], dict, dict]]:
    """Render and evaluate every run of one window (runs in a worker): (rows, summary, thumbnails) per job.

    Render once, share everywhere: the runs step through the window in lockstep (`drive_lockstep`) over one scene
    that keeps the latest frames' luminance per exposure (`CachedScene`: an exposure two runs or oracle candidates
    share is rendered once), one renderer (with `evaluate.share_render`, one sharp render per frame serves every
    exposure of every run) and one sensor that draws each frame's normal noise field once (`Sensor.remember_noise`).
    Every run's images are those it would get alone: the caches hold pure functions of (frame, exposure)."""
    from expoctl.controllers.base import Settings
    from expoctl.controllers.registry import ControllerContext, make_controller, needs, resolve_controller
    from expoctl.evaluation.run import WindowRun, drive_lockstep
    from expoctl.features.pipeline import make_frontend

    w = jobs[0].window
    if any(job.window != w for job in jobs):
        raise ValueError("run_window: every job must drive the same window")
    inputs = jobs[0].inputs
    ecfg, fcfg = inputs.evaluate, inputs.features
    sim = window_sim(inputs, w)
    scene, sensor, route, window, K = sim.scene, sim.sensor, sim.route, sim.frames, sim.K
    runs, warmups = [], []
    for job in jobs:
        if job.reference:  # a controller given by import path registers in this process too (spawned workers)
            resolve_controller(job.reference)
        config = inputs.controller_config(job.controller)
        # a controller that sees the scene may warm up for less (its config's warmup_frames: the oracle's)
        warmup = ecfg.warmup_frames
        if "scene" in needs(job.controller) and hasattr(config, "warmup_frames"):
            warmup = min(warmup, config.warmup_frames)
        context = ControllerContext(seed=w.seed, checkpoint=job.model_path, scene=scene, sensor=sensor,
                                    n_frames=w.traversal_frames, first_frame=max(0, w.start - warmup))
        controller = make_controller(job.controller, config, context)
        # front ends per run: their matchers keep state between frames
        frontends = {name: make_frontend(name, fcfg.config(name)) for name in ecfg.frontends}
        runs.append(WindowRun(
            controller, window, seed=w.seed, frontends=frontends, sumlog=job.sumlog,
            initial=Settings(ecfg.initial_gain_db, ecfg.initial_exposure_us), warmup_frames=warmup, K=K,
            vo_min_inliers=ecfg.vo.min_inliers, vo_n_features=ecfg.vo.n_features,
            vo_ransac_threshold_px=ecfg.vo.ransac_threshold_px, vo_map=ecfg.vo.map, thumb_width=ecfg.thumb_width,
            thumb_every=ecfg.thumb_every, thumb_span_s=ecfg.thumb_span_s))
        warmups.append(warmup)
    results = drive_lockstep(scene, sensor, runs)
    shared = {"window_renders": int(scene.n_renders), "window_sharp_renders": int(route.renderer.n_sharp_renders),
              "window_noise_draws": int(sensor.noise_draws)}
    out = []
    for job, run, warmup, (rows, summary, thumbs) in zip(jobs, runs, warmups, results):
        ident = {"run_id": job.run_id, "route_split": w.route_split, "city": w.city_name, "traversal": w.traversal,
                 "window": w.index, "window_label": w.label, "controller": job.controller}
        for r in rows:
            r.update(ident)
        summary.update(ident, warmup_frames=warmup, **shared)
        if job.controller == "oracle":
            timings = run.timed.inner.timings_ms
            summary["oracle_ms_median"] = float(np.median(timings)) if timings else np.nan
        out.append((rows, summary, thumbs))
    return out


@dataclass(frozen=True)
class WindowSim:
    """What every run of one window drives (`window_sim`): the trajectory, the route's scene (`route`, its renderer)
    behind the per-exposure cache every run reads (`scene`), the window's one sensor, which draws each frame's noise
    once (`Sensor.remember_noise`), the window's frames and annotations, and camera 1's intrinsics."""

    trajectory: Any
    route: Any  # expoctl.sim.closed_loop.RouteScene
    scene: Any  # expoctl.sim.oracle.CachedScene over `route`
    sensor: Any  # expoctl.camera.sensor.Sensor, noise remembered
    frames: Any  # expoctl.evaluation.run.WindowFrames of [start, stop)
    K: np.ndarray


def window_sim(inputs: EvaluationInputs, w: Window) -> WindowSim:
    """The one setup of a window's simulation, shared by evaluate (`run_window`) and the benchmark environment
    (expoctl.bench.env), so both see the same scene, sensor parameters, fixed-pattern noise and noise seeds:
    the sensor is randomised from the window's seed; the renderer is `inputs.render`."""
    import expoctl.sim.oracle as oracle_mod
    from expoctl.evaluation.run import WindowFrames
    from expoctl.sim.closed_loop import RouteScene, make_sensors, rig_metadata
    from expoctl.vo.frame_to_frame import intrinsics_matrix
    from expoctl.world import load_city_cached

    rig, render = inputs.rig, inputs.render
    city = load_city_cached(w.city, w.city_dir)
    traj = _traversal_cached(city, w, rig.fps)
    route = RouteScene(city, traj, rig, render)
    scene = oracle_mod.CachedScene(route)
    sensors, _ = make_sensors(inputs.sensor, render, 1, inputs.evaluate.sensor_randomisation, w.seed)
    sensor = sensors[0].remember_noise()
    section, dt, kind = window_annotations(traj, w.start, w.stop)
    frames = WindowFrames(w.sequence, range(w.start, w.stop), section, dt, kind, traj.poses[w.start:w.stop])
    K = intrinsics_matrix(rig_metadata(rig, render)["intrinsics"])
    return WindowSim(traj, route, scene, sensor, frames, K)


_TRAJ_CACHE: dict[tuple, Any] = {}


def _traversal_cached(city, w: Window, fps: float):
    """One trajectory per (city, traversal, length, fps, seed) per process: every controller of a window reuses it
    (two laps of poses take seconds to compute). Controllers never modify it."""
    return _trajectory_cached(city, w.traversal, w.traversal_frames, fps, w.traversal_seed)


def _trajectory_cached(city, traversal: int, n_frames: int, fps: float, seed: int):
    """`city.traversal(traversal, n_frames, fps, seed)`, kept for the last few keys: planning a traversal's windows
    (city_windows) and driving them (window_sim) compute the same two laps."""
    key = (id(city), traversal, n_frames, fps, seed)
    if key not in _TRAJ_CACHE:
        if len(_TRAJ_CACHE) >= 4:
            _TRAJ_CACHE.clear()
        _TRAJ_CACHE[key] = city.traversal(traversal, n_frames, fps, seed)
    return _TRAJ_CACHE[key]


def evaluate(inputs: EvaluationInputs, project_root: str | os.PathLike = ".",
             progress: bool = False, parallel: ParallelConfig | None = None) -> EvaluationResult:
    """Plan, tune SumLog, run every (window, controller) and aggregate (no files written). `parallel`: where the
    runs go (`run_jobs`); never changes a result."""
    project_root = Path(project_root)
    ecfg = inputs.evaluate
    check_controllers(ecfg.controllers, inputs)
    model_path = None
    if "learned" in ecfg.controllers:
        model_path = inputs.learned_model_path(project_root)
        if not model_path.is_file():
            raise InputError(f"{model_path}: trained model missing — the 'learned' controller cannot run; run the "
                             "train stage first (or drop 'learned' from evaluate.controllers)")
    windows = plan_windows(inputs, project_root)
    sumlog = tune_sumlog_params(inputs, project_root, ecfg.sumlog_pairs)
    return evaluate_windows(inputs, windows, sumlog, ecfg.controllers, model_path, progress, parallel)


def check_controllers(names, inputs: EvaluationInputs, references: dict[str, str] | None = None) -> None:
    """Build every controller of `names` that needs nothing at run time once, before any work: a plugin's
    constructor may refuse its config. `references`: {name: "module:attr"} of controllers given by import path."""
    from expoctl.controllers.registry import make_controller, needs, resolve_controller

    for ref in (references or {}).values():
        resolve_controller(ref)
    for name in names:
        if not needs(name):
            make_controller(name, inputs.controller_config(name))


def evaluate_windows(inputs: EvaluationInputs, windows: list[Window], sumlog: dict[str, SumLogParams],
                     controllers, model_path: str | os.PathLike | None = None, progress: bool = False,
                     parallel: ParallelConfig | None = None,
                     references: dict[str, str] | None = None) -> EvaluationResult:
    """Run every (window, controller) of `controllers` and aggregate: evaluate's work after planning and SumLog
    (`expoctl bench` calls it with its own controller list). `references`: {name: "module:attr"} for controllers
    given by import path, re-imported in each worker before it builds them."""
    references = dict(references or {})
    # the oracle is the slowest run: start those first so the pool does not end on one long job
    order = sorted(controllers, key=lambda c: c != "oracle")
    model = None if model_path is None else str(model_path)
    jobs = [RunJob(w, c, inputs, sumlog, model, reference=references.get(c)) for c in order for w in windows]
    rows: list[dict] = []
    summaries: list[dict] = []
    thumbs: dict[str, dict] = {}
    for job, (r, s, tb) in run_jobs(jobs, progress, parallel):
        rows.extend(r)
        summaries.append(s)
        thumbs[job.run_id] = tb
    frames = add_section_ids(pd.DataFrame(rows))
    runs = pd.DataFrame(summaries).sort_values("run_id").reset_index(drop=True)
    sections = section_stats(frames, inputs.evaluate.min_section_frames)
    metrics = build_metrics(sections, runs)
    problems = validate_metrics(metrics, tuple(controllers), [s for s in ROUTE_SPLITS if s in inputs.evaluate.splits],
                                inputs.evaluate.frontends)
    if problems:
        raise ValueError("metrics.json would break its schema (docs/evaluation.md): " + "; ".join(problems))
    return EvaluationResult(frames, runs, sections, metrics, sumlog, thumbs, windows)


def write_outputs(result: EvaluationResult, reports_dir: str | os.PathLike) -> dict[str, Path]:
    """reports/eval/ (swapped in whole) and reports/metrics.json, atomically."""
    import dataclasses

    from expoctl.io import atomic_dir, write_json

    reports_dir = Path(reports_dir)
    eval_dir = reports_dir / "eval"
    with atomic_dir(eval_dir) as tmp:
        result.frames.to_parquet(tmp / "frames.parquet", index=False)
        result.runs.to_parquet(tmp / "runs.parquet", index=False)
        result.sections.to_parquet(tmp / "sections.parquet", index=False)
        write_json({k: dataclasses.asdict(v) for k, v in result.sumlog.items()}, tmp / "sumlog.json")
        write_json([{**dataclasses.asdict(w), "sequence": w.sequence} for w in result.windows], tmp / "windows.json")
        (tmp / "thumbs").mkdir()
        for run_id, tb in result.thumbs.items():
            np.savez_compressed(tmp / "thumbs" / f"{run_id}.npz", **tb)
    write_json(result.metrics, reports_dir / "metrics.json")
    return {"metrics": reports_dir / "metrics.json", "eval_dir": eval_dir}


def run_jobs(jobs: list[RunJob], progress: bool = False,
             parallel: ParallelConfig | None = None) -> Iterator[tuple[RunJob, tuple]]:
    """(job, (rows, summary, thumbnails)) for every job, in the order of `jobs`. The jobs of one window go to one
    worker together (`run_window`: rendered once, driven in lockstep); windows fan out where `parallel` says
    (`expoctl.parallel`: `parallel.n_jobs` spawned worker processes, one thread each, or this process when it is 1,
    the default).
    """
    from tqdm import tqdm

    groups: dict[str, list[int]] = {}
    for i, job in enumerate(jobs):
        groups.setdefault(job.window.sequence, []).append(i)
    # the slowest window (most runs; an oracle among them) first, so the pool does not end on one long job
    order = sorted(groups.values(), key=lambda ix: (-len(ix), not any(jobs[i].controller == "oracle" for i in ix)))
    done: dict[int, tuple] = {}
    following = 0
    with tqdm(total=len(jobs), desc="evaluate", unit="run", disable=not progress) as bar:
        windows = [tuple(jobs[i] for i in ix) for ix in order]
        for (ix, (_group, results)) in zip(order, run_ordered(run_window, windows, None, parallel,
                                                                 progress=lambda g, _r: bar.update(len(g)))):
            done.update(zip(ix, results))
            while following in done:  # the caller aggregates in job order: hand on every job that is complete
                yield jobs[following], done.pop(following)
                following += 1


def metrics_summary(metrics: dict[str, Any]) -> dict[str, float]:
    """Flat {split.controller.kind.frontend.stat: value} for logging (None values dropped)."""
    out = {}
    for split, ctrls in metrics.items():
        for ctrl, e in ctrls.items():
            for kind in ("static", "dynamic"):
                for fe, m in e[kind].items():
                    for stat, v in m.items():
                        if v is not None:
                            out[f"{split}.{ctrl}.{kind}.{fe}.{stat}"] = float(v)
            n_ok, n = e["tracking_success"]
            out[f"{split}.{ctrl}.tracking_success_rate"] = n_ok / n
    return out
