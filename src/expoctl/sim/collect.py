"""Collect raw dual-camera sequences with the simulated rig (the `collect` stage; paper §III-B data collection).

Camera 1 runs the reference controller (AG+AE in iteration 1, the learned network in iteration 2); camera 2 gets
camera 1's settings perturbed through the paper's quadrant cycle (`expoctl.sim.protocol`). One sequence per job:

- every split: `n_sequences` traversals of its city (`world.cities.<split>`; indices first_traversal, +1, …), each with
  its own speed, sun and sky drawn by the world. With `frames: N` a traversal is an N-frame window that the world
  places around a tunnel transition (portal chosen by index, position random within the middle 60 %), so training
  data is rich in the portals that matter; with `frames: null` it is the whole closed route (validation / test).
- camera 1's controller first runs `warmup_frames` unrecorded frames (the rig was already running).

Output: `<out_dir>/<split>/<sequence>/` in the docs/raw_format.md format, written through `SequenceWriter` (atomic per
sequence). The whole `out_dir` is also built beside the target and swapped in only when every sequence succeeded,
so a failed or interrupted run leaves the previous data untouched and no stale sequences survive a config change.

Config used (whole resolved config): `collect`, `rig`, `sensor`, `world` (cities, city_dir, render), `seed`,
`controllers.<reference_controller>`.
"""

from __future__ import annotations

import os
import time
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, GAIN_DB_MAX, GAIN_DB_MIN, SENSOR_EXPOSURE_US_MIN
from expoctl.controllers.base import Settings
from expoctl.errors import ConfigError
from expoctl.host import single_threaded_children
from expoctl.sim.closed_loop import (
    RenderConfig,
    RigConfig,
    RouteScene,
    clip_sections,
    make_sensors,
    reject_unknown_keys,
    rig_metadata,
    run_closed_loop,
)
from expoctl.raw.format import SequenceWriter

SPLITS = ("train", "validation", "test")


@dataclass(frozen=True)
class SplitConfig:
    """Which sequences one split gets (config `collect.splits.<name>`)."""

    name: str
    first_traversal: int = 0
    n_sequences: int = 0
    frames: int | None = None  # recorded frames per sequence; None: the whole route (minus warm-up)


@dataclass(frozen=True)
class CollectConfig:
    """Config group `collect`."""

    reference_controller: str
    initial_gain_db: float
    initial_exposure_us: float
    warmup_frames: int
    sensor_randomisation: float
    n_jobs: int
    splits: dict[str, SplitConfig]

    @classmethod
    def from_dict(cls, d: Any, key: str = "collect") -> "CollectConfig":
        d = _mapping(d, key)
        known = {"reference_controller", "initial_gain_db", "initial_exposure_us", "warmup_frames",
                 "sensor_randomisation", "n_jobs", "splits"}
        _no_unknown(d, known, key)
        _require_keys(d, known, key)
        name = d["reference_controller"]
        if not isinstance(name, str) or not name:
            raise ConfigError(f"{key}.reference_controller", f"must be a controller name, got {name!r}")
        gain = _num(d, "initial_gain_db", key)
        if not GAIN_DB_MIN <= gain <= GAIN_DB_MAX:
            raise ConfigError(f"{key}.initial_gain_db", f"must be in [{GAIN_DB_MIN}, {GAIN_DB_MAX}] dB, got {gain}")
        exposure = _num(d, "initial_exposure_us", key)
        if not SENSOR_EXPOSURE_US_MIN <= exposure <= EXPOSURE_US_MAX:
            raise ConfigError(f"{key}.initial_exposure_us",
                              f"must be in [{SENSOR_EXPOSURE_US_MIN}, {EXPOSURE_US_MAX}] µs, got {exposure}")
        warmup = _int(d, "warmup_frames", key, 0)
        amp = _num(d, "sensor_randomisation", key)
        if not 0.0 <= amp <= 0.5:
            raise ConfigError(f"{key}.sensor_randomisation", f"must be a fraction in [0, 0.5] (spec: 0.1–0.2), got {amp}")
        n_jobs = _int(d, "n_jobs", key, 1)
        splits_d = _mapping(d["splits"], f"{key}.splits")
        _no_unknown(splits_d, set(SPLITS), f"{key}.splits")
        splits = {s: _split_from_dict(s, splits_d.get(s), f"{key}.splits.{s}") for s in SPLITS}
        return cls(name, gain, exposure, warmup, amp, n_jobs, splits)


@dataclass(frozen=True)
class SequenceJob:
    """Everything one worker needs to render one sequence (picklable)."""

    split: str
    name: str
    city: str | dict  # world.cities.<split>: a city name or a world city config mapping
    city_dir: str | None  # world.city_dir, absolute
    city_name: str
    traversal: int
    traversal_frames: int | None  # what the world is asked for (warm-up + recorded); None: whole route
    traversal_seed: int
    warmup_frames: int  # leading frames of the traversal run unrecorded
    seed: int  # sequence seed: sensor randomisation, sensor noise, perturbation


def derive_seed(*parts: int | str) -> int:
    """A stable 63-bit seed from ints and strings (strings through CRC32; Python's hash() is salted per process)."""
    ints = [p if isinstance(p, int) else zlib.crc32(p.encode()) for p in parts]
    lo, hi = (int(x) for x in np.random.SeedSequence(ints).generate_state(2, dtype=np.uint32))
    return (hi >> 1) << 32 | lo


def plan_sequences(cfg: dict[str, Any], project_root: str | os.PathLike = ".") -> list[SequenceJob]:
    """The sequences `collect` will write, in order (no rendering). Relative `world.city_dir` is under `project_root`."""
    from expoctl.world.cities import resolve_city_name

    ccfg = CollectConfig.from_dict(cfg.get("collect"))
    base_seed = config_seed(cfg)
    world = cfg.get("world") or {}
    if not isinstance(world, dict):
        raise ConfigError("world", f"must be a mapping, got {world!r}")
    city_dir = world.get("city_dir")
    if city_dir is not None:
        if not isinstance(city_dir, str):
            raise ConfigError("world.city_dir", f"must be a directory path or null, got {city_dir!r}")
        city_dir = str((Path(project_root) / city_dir).resolve())
    cities = world.get("cities") or {}
    if not isinstance(cities, dict):
        raise ConfigError("world.cities", f"must map split → city, got {cities!r}")
    jobs: list[SequenceJob] = []
    for split in SPLITS:
        scfg = ccfg.splits[split]
        if scfg.n_sequences == 0:
            continue
        if split not in cities:
            raise ConfigError(f"world.cities.{split}", f"missing: collect.splits.{split} asks for {scfg.n_sequences} sequences")
        city = cities[split]
        city_name = resolve_city_name(city, city_dir, f"world.cities.{split}")
        for k in range(scfg.n_sequences):
            index = scfg.first_traversal + k
            jobs.append(SequenceJob(
                split=split,
                name=f"{split}-{city_name}-t{index:03d}",
                city=city,
                city_dir=city_dir,
                city_name=city_name,
                traversal=index,
                traversal_frames=None if scfg.frames is None else ccfg.warmup_frames + scfg.frames,
                traversal_seed=derive_seed(base_seed, "traversal", split),
                warmup_frames=ccfg.warmup_frames,
                seed=derive_seed(base_seed, "sequence", split, city_name, index),
            ))
    return jobs


def collect(cfg: dict[str, Any], out_dir: str | os.PathLike, progress: bool | Callable[[str], None] = True,
            project_root: str | os.PathLike = ".") -> list[dict[str, Any]]:
    """Render every planned sequence into `out_dir/<split>/<sequence>/`; return one summary dict per sequence.
    `progress`: True = a tqdm bar, a callable = one line per finished sequence (e.g. a logger), False = quiet."""
    from expoctl.controllers.registry import make_controller
    from expoctl.io import atomic_dir

    from expoctl.camera.sensor import SensorConfig

    # validate everything before any work: config groups, the reference controller's params, city names
    ccfg = CollectConfig.from_dict(cfg.get("collect"))
    RigConfig.from_dict(cfg.get("rig"))
    RenderConfig.from_world(cfg.get("world"))
    SensorConfig.from_dict(cfg.get("sensor") or {})
    make_controller(ccfg.reference_controller, _reference_params(cfg, ccfg))
    jobs = plan_sequences(cfg, project_root)
    out_dir = Path(out_dir)
    summaries: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    with atomic_dir(out_dir) as tmp_root:
        for summary in _run_jobs(cfg, jobs, tmp_root, ccfg.n_jobs, progress is True):
            summaries.append(summary)
            if callable(progress):
                progress(f"{len(summaries)}/{len(jobs)} {summary['sequence']}: {summary['n_frames']} frame pairs "
                         f"({time.perf_counter() - t0:.0f} s elapsed)")
    order = {j.name: i for i, j in enumerate(jobs)}
    return sorted(summaries, key=lambda s: order[s["sequence"]])


def collect_sequence(cfg: dict[str, Any], job: SequenceJob, root: str | os.PathLike) -> dict[str, Any]:
    """Render one sequence into `root/<split>/<name>/` and return its summary (runs in a worker process)."""
    from expoctl.controllers.registry import make_controller
    from expoctl.world import load_city_cached

    ccfg = CollectConfig.from_dict(cfg.get("collect"))
    rig = RigConfig.from_dict(cfg.get("rig"))
    render = RenderConfig.from_world(cfg.get("world"))
    city = load_city_cached(job.city, job.city_dir)
    traj = city.traversal(job.traversal, job.traversal_frames, rig.fps, job.traversal_seed)
    scene = RouteScene(city, traj, rig, render)
    sensors, sensor_log = make_sensors(cfg.get("sensor"), render, 2, ccfg.sensor_randomisation, job.seed)
    controller = make_controller(ccfg.reference_controller, _reference_params(cfg, ccfg))
    n_total = len(traj.timestamps_ns)
    first = job.warmup_frames
    if n_total - first < 2:
        raise ConfigError(f"collect.splits.{job.split}", f"traversal {job.traversal} of city {job.city_name!r} has {n_total} "
                          f"frames: not enough after {first} warm-up frames (lower collect.warmup_frames)")
    frames = range(first, n_total)
    meta = {
        "source": "sim",
        "rig": rig_metadata(rig, render),
        "world": job.city_name,
        "route": f"{job.city_name}/traversal-{job.traversal:03d}",
        "split": job.split,
        "traversal": {"index": job.traversal, "seed": job.traversal_seed, "first_recorded_frame": first,
                      "speed_mps": float(traj.speed_mps)},
        "reference_controller": {"name": ccfg.reference_controller, "params": _reference_params(cfg, ccfg)},
        "seed": job.seed,
        "sections": clip_sections(traj.sections, first, n_total),
        "initial_settings": {"gain_db": ccfg.initial_gain_db, "exposure_us": ccfg.initial_exposure_us},
        "warmup_frames": first,
        "perturbation": rig.perturbation.to_dict(),
        "sensor": sensor_log,
    }
    gains, exposures = [], []
    with SequenceWriter(Path(root) / job.split / job.name, meta) as writer:
        loop = run_closed_loop(scene, sensors, controller, Settings(ccfg.initial_gain_db, ccfg.initial_exposure_us),
                               frames, job.seed, perturbation=rig.perturbation, warmup_frames=first)
        for frame in loop:
            for cam in frame.cameras:
                writer.add_frame(frame.frame_index - first, cam.camera, frame.timestamp_ns,
                                 cam.settings.gain_db, cam.settings.exposure_us, cam.image)
                if cam.camera == 1:
                    gains.append(cam.settings.gain_db)
                    exposures.append(cam.settings.exposure_us)
    return {
        "sequence": job.name,
        "split": job.split,
        "n_frames": len(frames),
        "n_dynamic_sections": sum(1 for s in meta["sections"] if s["kind"] == "dynamic"),
        "cam1_gain_db_max": float(np.max(gains)),
        "cam1_exposure_us_min": float(np.min(exposures)),
        "cam1_exposure_us_max": float(np.max(exposures)),
    }


# --- internals ------------------------------------------------------------------------------------------------------


def _split_from_dict(name: str, d: Any, key: str) -> SplitConfig:
    if d is None:  # a split left out collects nothing
        return SplitConfig(name=name, n_sequences=0)
    d = _mapping(d, key)
    _no_unknown(d, {"first_traversal", "n_sequences", "frames"}, key)
    _require_keys(d, {"n_sequences", "frames"}, key)
    return SplitConfig(
        name=name,
        first_traversal=_int(d, "first_traversal", key, 0) if "first_traversal" in d else 0,
        n_sequences=_int(d, "n_sequences", key, 0),
        frames=None if d["frames"] is None else _int(d, "frames", key, 2),
    )


def _mapping(d: Any, key: str) -> dict:
    if not isinstance(d, dict):
        raise ConfigError(key, f"missing or not a mapping (got {d!r})")
    return d


# the rig config's unknown-key check, shared rather than written twice
_no_unknown = reject_unknown_keys


def _require_keys(d: dict, needed: set[str], key: str) -> None:
    for k in sorted(needed):
        if k not in d:
            raise ConfigError(f"{key}.{k}", "missing")


def _num(d: dict, k: str, key: str) -> float:
    v = d[k]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ConfigError(f"{key}.{k}", f"must be a finite number, got {v!r}")
    return float(v)


def _int(d: dict, k: str, key: str, minimum: int) -> int:
    v = d[k]
    if isinstance(v, bool) or not isinstance(v, int) or v < minimum:
        raise ConfigError(f"{key}.{k}", f"must be an integer >= {minimum}, got {v!r}")
    return v


def config_seed(cfg: dict[str, Any]) -> int:
    """The run's base seed, config key `seed` (a non-negative integer; default 0)."""
    seed = cfg.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError("seed", f"must be a non-negative integer, got {seed!r}")
    return seed


def _reference_params(cfg: dict[str, Any], ccfg: CollectConfig) -> dict:
    """The reference controller's config section: controllers.<name> (shared with evaluation), or {}."""
    section = (cfg.get("controllers") or {}).get(ccfg.reference_controller)
    if section is None:
        return {}
    if not isinstance(section, dict):
        raise ConfigError(f"controllers.{ccfg.reference_controller}", f"must be a mapping, got {section!r}")
    return section


def _run_jobs(cfg: dict, jobs: list[SequenceJob], root: Path, n_jobs: int, progress: bool) -> Iterator[dict]:
    from tqdm import tqdm

    bar = tqdm(total=len(jobs), desc="collect", unit="seq", disable=not progress)
    try:
        if n_jobs <= 1 or len(jobs) <= 1:
            for job in jobs:
                yield collect_sequence(cfg, job, root)
                bar.update()
            return
        # spawn (not fork): workers may load torch (learned reference controller), which is not fork-safe;
        # one BLAS/torch thread per worker so n_jobs processes do not oversubscribe the cores
        with single_threaded_children(), ProcessPoolExecutor(max_workers=n_jobs, mp_context=get_context("spawn")) as pool:
            futures = [pool.submit(collect_sequence, cfg, job, root) for job in jobs]
            try:
                for fut in as_completed(futures):
                    yield fut.result()
                    bar.update()
            except BaseException:
                for f in futures:
                    f.cancel()
                raise
    finally:
        bar.close()
