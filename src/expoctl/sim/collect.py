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

Config used: `CollectInputs`, built once by the collect stage from the resolved config's `collect`, `rig`, `sensor`,
`world` (cities, city_dir, render), `seed`, `controllers.<reference_controller>` and `parallel` (where the
sequences render: `expoctl.parallel`; it never changes a byte).
"""

from __future__ import annotations

import os
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, GAIN_DB_MAX, GAIN_DB_MIN, SENSOR_EXPOSURE_US_MIN
from expoctl.camera.sensor import SensorConfig
from expoctl.config_reader import Problems, Section, read_seed
from expoctl.controllers.base import Settings
from expoctl.errors import ConfigError
from expoctl.parallel import MOVED_N_JOBS, ParallelConfig, run_ordered
from expoctl.raw.format import SequenceWriter
from expoctl.sim.closed_loop import RigConfig, RouteScene, clip_sections, make_sensors, rig_metadata, run_closed_loop
from expoctl.world.city import WorldConfig

SPLITS = ("train", "validation", "test")
#: collect.source: `simulator` renders the sequences; `recordings` copies the real rig recordings of data/recordings
#: instead (expoctl.raw.recordings), so the pipeline trains on real data
SOURCES = ("simulator", "recordings")


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
    splits: dict[str, SplitConfig]
    source: str = "simulator"

    @classmethod
    def from_dict(cls, d: Any, key: str = "collect", problems: Problems | None = None) -> "CollectConfig":
        r = Section(d, key, problems, required=True)
        cfg = cls(
            reference_controller=r.text("reference_controller"),
            initial_gain_db=r.number("initial_gain_db", min=GAIN_DB_MIN, max=GAIN_DB_MAX, unit="dB"),
            initial_exposure_us=r.number("initial_exposure_us", min=SENSOR_EXPOSURE_US_MIN, max=EXPOSURE_US_MAX,
                                         unit="µs"),
            warmup_frames=r.integer("warmup_frames", min=0),
            sensor_randomisation=r.number("sensor_randomisation", min=0.0, max=0.5),  # spec: 0.1–0.2
            splits=_splits(r.section("splits", required=True)),
            source=r.choice("source", SOURCES, "simulator"),
        )
        r.moved("n_jobs", "parallel.n_jobs", MOVED_N_JOBS)
        r.done()
        return cfg


@dataclass(frozen=True)
class CollectInputs:
    """Everything `collect` reads from the resolved config, checked and typed once (by the collect stage): the
    `collect`, `world`, `rig` and `sensor` groups, `seed`, and the reference controller's `controllers.<name>`."""

    collect: CollectConfig
    seed: int
    world: WorldConfig
    rig: RigConfig
    sensor: SensorConfig
    reference_config: Any  # controllers.<collect.reference_controller>, typed (None: its name is not a controller)
    reference_section: dict  # the same section as the config gave it: each sequence's metadata records it
    parallel: ParallelConfig = field(default_factory=ParallelConfig)  # where the sequences render (never what)

    @classmethod
    def from_resolved(cls, cfg: dict[str, Any]) -> "CollectInputs":
        """Build from the resolved config; every problem of every group is reported at once (ConfigError)."""
        problems = Problems()
        top = Section(cfg, "", problems)
        ccfg = CollectConfig.from_dict(top.value("collect", None), "collect", problems)
        controllers = top.section("controllers")
        inputs = cls(ccfg, read_seed(top), WorldConfig.from_dict(top.value("world", None), "world", problems),
                     RigConfig.from_dict(top.value("rig", None), "rig", problems),
                     SensorConfig.from_dict(top.value("sensor", None), "sensor", problems),
                     reference_controller_config(controllers, ccfg.reference_controller, "collect.reference_controller"),
                     _as_given(controllers.mapping.get(ccfg.reference_controller)),
                     ParallelConfig.from_dict(top.value("parallel", None), "parallel", problems))
        problems.raise_if_any()
        return inputs


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


def plan_sequences(inputs: CollectInputs, project_root: str | os.PathLike = ".") -> list[SequenceJob]:
    """The sequences `collect` will write, in order (no rendering). Relative `world.city_dir` is under `project_root`."""
    from expoctl.world.cities import resolve_city_name

    ccfg, base_seed = inputs.collect, inputs.seed
    world = inputs.world.under(project_root)
    city_dir, cities = world.city_dir, world.cities
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


#: with a callable `progress` (a logger under DVC, no tty): a line per sequence in progress at least this often
PROGRESS_EVERY_S = 30.0


class FrameProgress:
    """Called with the frame pairs recorded so far in one sequence and its total; emits "<sequence>: <done>/<total>
    frame pairs, <elapsed> s, <rate> frame pairs/s" when `every_s` seconds have passed since the last line (0: every
    frame)."""

    def __init__(self, emit: Callable[[str], None], sequence: str, every_s: float = PROGRESS_EVERY_S):
        self.emit, self.sequence, self.every_s = emit, sequence, every_s
        self.t0 = self.last = time.perf_counter()

    def __call__(self, done: int, total: int) -> None:
        now = time.perf_counter()
        if now - self.last < self.every_s:
            return
        self.last = now
        elapsed = now - self.t0
        self.emit(f"{self.sequence}: {done}/{total} frame pairs, {elapsed:.0f} s, "
                  f"{done / max(elapsed, 1e-9):.2f} frame pairs/s")


def collect(inputs: CollectInputs, out_dir: str | os.PathLike, progress: bool | Callable[[str], None] = True,
            project_root: str | os.PathLike = ".", progress_every_s: float = PROGRESS_EVERY_S) -> list[dict[str, Any]]:
    """Render every planned sequence into `out_dir/<split>/<sequence>/`; return one summary dict per sequence.
    `progress`: True = a tqdm bar, a callable = a line per finished sequence (e.g. a logger) and, every
    `progress_every_s` seconds while a sequence renders, its frames done / total, elapsed time and rate (from the
    worker processes too); False = quiet. Progress never changes the data written."""
    from expoctl.controllers.registry import make_controller
    from expoctl.io import atomic_dir

    # check before any work what the config groups could not: the reference controller's params, the city names
    make_controller(inputs.collect.reference_controller, inputs.reference_config)
    jobs = plan_sequences(inputs, project_root)
    out_dir = Path(out_dir)
    summaries: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    finished = 0

    def done(summary: dict[str, Any]) -> None:  # as each sequence finishes, whatever the order
        nonlocal finished
        finished += 1
        if callable(progress):
            progress(f"{finished}/{len(jobs)} {summary['sequence']}: {summary['n_frames']} frame pairs "
                     f"({time.perf_counter() - t0:.0f} s elapsed)")

    with atomic_dir(out_dir) as tmp_root:
        lines = progress if callable(progress) else None
        summaries = list(_run_jobs(inputs, jobs, tmp_root, progress is True, lines,
                                   progress_every_s, done))
    order = {j.name: i for i, j in enumerate(jobs)}
    return sorted(summaries, key=lambda s: order[s["sequence"]])


def collect_sequence(inputs: CollectInputs, job: SequenceJob, root: str | os.PathLike,
                     progress: Callable[[int, int], None] | None = None) -> dict[str, Any]:
    """Render one sequence into `root/<split>/<name>/` and return its summary (runs in a worker process).
    `progress` (e.g. a `FrameProgress`) is called with (frame pairs written, total) after each one."""
    from expoctl.controllers.registry import make_controller
    from expoctl.world import load_city_cached

    ccfg, rig, render = inputs.collect, inputs.rig, inputs.world.render
    city = load_city_cached(job.city, job.city_dir)
    traj = city.traversal(job.traversal, job.traversal_frames, rig.fps, job.traversal_seed)
    scene = RouteScene(city, traj, rig, render)
    sensors, sensor_log = make_sensors(inputs.sensor, render, 2, ccfg.sensor_randomisation, job.seed)
    controller = make_controller(ccfg.reference_controller, inputs.reference_config)
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
        "reference_controller": {"name": ccfg.reference_controller, "params": inputs.reference_section},
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
            if progress is not None:
                progress(frame.frame_index - first + 1, len(frames))
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


def _splits(r: Section) -> dict[str, SplitConfig]:
    """`collect.splits`: every split's SplitConfig (a split left out collects nothing)."""
    out = {}
    for name in SPLITS:
        if not r.has(name) or r.value(name) is None:
            out[name] = SplitConfig(name=name, n_sequences=0)
            continue
        sr = r.section(name)
        out[name] = SplitConfig(name=name, first_traversal=sr.integer("first_traversal", 0, min=0),
                                n_sequences=sr.integer("n_sequences", min=0),
                                frames=sr.integer("frames", min=2, nullable=True))
        sr.done()
    r.done()
    return out


def _as_given(section: Any) -> dict:
    """A config section as given, for the record ({} when absent or not a mapping: that is reported elsewhere)."""
    return dict(section) if isinstance(section, dict) else {}


def reference_controller_config(controllers: Section, name: str | None, key: str) -> Any:
    """The typed config of the controller `name` that drives camera 1 (`controllers.<name>`, absent: defaults),
    its problems added to the section's; None if `name` is not a registered controller or needs the simulator's
    scene (a problem at `key`)."""
    from expoctl.controllers.registry import CONTROLLERS, controller_names

    if name is None:
        return None
    usable = ", ".join(controller_names(runs_without=("scene",)))
    if name in CONTROLLERS and "scene" in CONTROLLERS.get(name).info.get("needs", ()):
        controllers.problems.add(key, f"{name!r} cannot drive collect (it renders candidate frames from the "
                                      f"simulator's scene, which only evaluate gives it); use one of: {usable}")
        return None
    if name not in CONTROLLERS:
        broken = CONTROLLERS.broken().get(name)
        controllers.problems.add(key, f"unknown controller {name!r} (known: {usable})" if broken is None else
                                 f"controller plugin {name!r} (package {broken[0]}) is broken: {broken[1]}")
        return None
    entry = CONTROLLERS.get(name, key)
    sub = controllers.section(name)
    config = sub.read(entry.config)
    sub.done()
    return config


def _run_jobs(inputs: CollectInputs, jobs: list[SequenceJob], root: Path, progress: bool,
              lines: Callable[[str], None] | None = None, every_s: float = PROGRESS_EVERY_S,
              done: Callable[[dict], None] | None = None) -> Iterator[dict]:
    """Each sequence's summary, in plan order, rendered where `inputs.parallel` says (`expoctl.parallel`). `lines`:
    where the in-sequence progress lines go (`FrameProgress`); from workers they come back while the sequences
    render. `done(summary)`: called as each sequence finishes."""
    from tqdm import tqdm

    tasks = [_SequenceTask(inputs, job, str(root), every_s) for job in jobs]
    with tqdm(total=len(jobs), desc="collect", unit="seq", disable=not progress) as bar:
        for _, summary in run_ordered(_collect_task if lines is not None else _collect_task_quiet, tasks, None,
                                      inputs.parallel, progress=lambda _t, s: (bar.update(), done and done(s)),
                                      messages=lines):
            yield summary


@dataclass(frozen=True)
class _SequenceTask:
    """One worker job: a sequence to render under `root` (picklable)."""

    inputs: CollectInputs
    job: SequenceJob
    root: str
    every_s: float


def _collect_task(task: _SequenceTask, emit: Callable[[str], None]) -> dict[str, Any]:
    return collect_sequence(task.inputs, task.job, task.root, FrameProgress(emit, task.job.name, task.every_s))


def _collect_task_quiet(task: _SequenceTask) -> dict[str, Any]:
    return collect_sequence(task.inputs, task.job, task.root)
