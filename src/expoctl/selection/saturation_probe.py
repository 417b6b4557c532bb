"""Does a controller recover from a badly exposed start? A closed-loop probe of its fixed points.

Why: open-loop metrics (validation loss, `expoctl.net.follow`) describe a network in the states its training data
contain: camera 1 under a well-exposed reference, camera 2 within about ±1 EV of it. In closed loop the network also
meets states its data never contain, and the worst of them is a saturated frame: it shows almost nothing of the
scene, so nothing in the image tells the network how far to step down. If its step there is about zero, saturation is
an absorbing state and the controller stays white. Measured (docs/runs/old_camera_results.md): every network that diverged in the
evaluation ended this probe with 97–100 % of the frame clipped from some start; no sound one did. The dark side is
the mirror image: a black frame shows as little, and two calibrated-camera networks settled 3–9 EV below AG+AE with
nothing clipped white (docs/runs/calibrated_seeds/README.md), so the probe also counts black pixels.

Protocol: the real simulator and sensor (one city, one traversal no stage collects or evaluates, e.g. 900), in closed
loop, from one start frame in the middle of the route's longest open-road (static) stretch and one in the middle of
its longest tunnel interior. AG+AE first runs `frames` frames from its own start to give the reference level P_ref
(its exposure product over the last `last_frames` frames). Then each controller runs the same frames from
P_ref·2^k for each offset k (exposure first, then gain), with no warm-up. Per controller, start and k: the offset of
its exposure product from P_ref over the last frames (EV), its mean step over the first `first_frames` frames, and
the clipped share (grey ≥ 250) and the black share (grey ≤ 5) of the last frame. One attracting fixed point shows as
the same final offset from every k; an absorbing saturated state as final offset ≈ k, step ≈ 0 and a white (or black)
last frame. A controller fails when some start ends with at least `max_saturated_fraction` of the frame clipped or
at least `max_dark_fraction` of it black.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, TYPE_CHECKING

import numpy as np

from expoctl.camera.ranges import exposure_value_ev
from expoctl.camera.response import DARK_DN, SATURATED_DN  # as evaluate's dark_frac and saturated_frac
from expoctl.controllers.agae import split_exposure_first
from expoctl.controllers.base import Controller, Settings
from expoctl.config_reader import Problems, Section
from expoctl.errors import ConfigError, InputError

if TYPE_CHECKING:
    from expoctl.camera.sensor import SensorConfig
    from expoctl.sim.closed_loop import RigConfig
    from expoctl.world.city import WorldConfig

AGAE_START = Settings(0.0, 5000.0)  # AG+AE's own start before it settles to the reference level


@dataclass(frozen=True)
class ProbeConfig:
    """conf/select_model/default.yaml `probe` (validated by `from_dict`)."""

    enabled: bool = True
    city: str = "train"
    traversal: int = 900
    seed: int = 0  # the traversal's conditions and noise: fixed, so every run's networks face the same test
    frames: int = 60
    offsets_ev: tuple[float, ...] = (0.0, 6.0)
    width: int = 320
    height: int = 240
    max_saturated_fraction: float = 0.97  # a candidate fails when some start ends with at least this share clipped
    max_dark_fraction: float | None = 0.97  # … or with at least this share black; None: white clipping only
    last_frames: int = 10
    first_frames: int = 10

    @classmethod
    def from_dict(cls, d, key: str, problems: Problems | None = None) -> "ProbeConfig":
        r = Section(d, key, problems)
        frames = r.integer("frames", cls.frames, min=2)
        # the reference level is the mean over the last frames of a start, the verdict over its first ones
        ends = {name: r.integer(name, getattr(cls, name), min=1, below=frames) for name in ("last_frames",
                                                                                             "first_frames")}
        cfg = cls(
            enabled=r.boolean("enabled", cls.enabled),
            city=r.text("city", cls.city),  # a world.cities entry (make_probe checks it)
            traversal=r.integer("traversal", cls.traversal, min=0),
            seed=r.integer("seed", cls.seed, min=0),
            frames=frames,
            offsets_ev=r.numbers("offsets_ev", cls.offsets_ev),
            width=r.integer("width", cls.width, min=16),
            height=r.integer("height", cls.height, min=16),
            max_saturated_fraction=r.number("max_saturated_fraction", cls.max_saturated_fraction, above=0.0, max=1.0),
            max_dark_fraction=r.number("max_dark_fraction", cls.max_dark_fraction, above=0.0, max=1.0, nullable=True),
            **ends,
        )
        r.done()
        return cfg


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    """(start, length) of the longest run of True in mask (the first one on a tie)."""
    best, start = (0, 0), None
    for i, m in enumerate(np.append(np.asarray(mask, bool), False)):
        if m and start is None:
            start = i
        elif not m and start is not None:
            if i - start > best[1]:
                best = (start, i - start)
            start = None
    return best


def start_frames(trajectory, n_frames: int) -> dict[str, int]:
    """First frame of each probe run: the middle of the longest static open-road stretch and of the longest stretch
    inside a tunnel, minus half a run. Raises InputError when a stretch is shorter than a run."""
    static = np.asarray(trajectory.frame_section) == "static"
    t = np.arange(len(static)) / trajectory.fps
    inside = np.zeros(len(static), bool)  # after an entry crossing and before the next exit
    crossings = sorted(trajectory.portal_times_s)
    for (t_in, _, kind), nxt in zip(crossings, crossings[1:] + [(math.inf, None, "exit")]):
        if kind == "entry":
            inside |= (t >= t_in) & (t < nxt[0])
    if crossings and crossings[0][2] == "exit":  # the traversal starts inside a tunnel
        inside |= t < crossings[0][0]
    out = {}
    for name, mask in (("open_road", static & ~inside), ("tunnel", inside)):
        s, n = _longest_run(mask)
        if n < n_frames:
            raise InputError(f"saturation probe: the longest {name} stretch of the traversal has {n} frames, fewer "
                             f"than the probe's {n_frames}")
        out[name] = s + (n - n_frames) // 2
    return out


def settings_at(ev: float) -> Settings:
    """Exposure-first settings at exposure value `ev` (`exposure_value_ev`: log2 of t·gain with t in seconds),
    clipped to the camera's ranges."""
    return split_exposure_first(ev * math.log(2.0) + math.log(1e6))  # the split works on ln(t in µs · gain)


def _ev(s: Settings) -> float:
    return float(exposure_value_ev(s.gain_db, s.exposure_us))


class SaturationProbe:
    """The probe's scene and reference levels, built once and run for any number of controllers."""

    def __init__(self, pcfg: ProbeConfig, city, rig, render, sensor: "SensorConfig", agae: Controller):
        from expoctl.sim.closed_loop import RouteScene, make_sensors

        self.cfg = pcfg
        self.trajectory = city.traversal(pcfg.traversal, None, rig.fps, pcfg.seed)
        self.scene = RouteScene(city, self.trajectory, rig, render.with_size(pcfg.width, pcfg.height))
        self.sensor = make_sensors(sensor, render.with_size(pcfg.width, pcfg.height), 1, 0.0, pcfg.seed)[0][0]
        self.starts = {}
        for name, frame in start_frames(self.trajectory, pcfg.frames).items():
            evs, _, _ = self._drive(agae, AGAE_START, frame)
            ref = float(evs[-pcfg.last_frames:].mean())
            # the camera's ranges clip some starts (e.g. −4 EV in daylight): record where each run really starts
            offsets = [_ev(settings_at(ref + k)) - ref for k in pcfg.offsets_ev]
            self.starts[name] = {"frame": int(frame), "agae_ref_ev": ref, "start_offsets_ev": offsets}

    def _drive(self, controller: Controller, initial: Settings, start: int) -> tuple[np.ndarray, float, float]:
        """Per-frame EV of the applied settings, and the clipped and black shares of the last frame."""
        from expoctl.sim.closed_loop import run_closed_loop

        evs, last = [], None
        for f in run_closed_loop(self.scene, [self.sensor], controller, initial,
                                 range(start, start + self.cfg.frames), self.cfg.seed):
            last = f.camera(1)
            evs.append(_ev(last.settings))
        grey = last.image.mean(axis=2)  # the last frame only
        return np.array(evs), float((grey >= SATURATED_DN).mean()), float((grey <= DARK_DN).mean())

    def run(self, controller: Controller) -> dict:
        """{start name: [per offset: k_ev, start/final offset (EV), mean first step (EV/frame), final clipped
        and black shares, per-frame offsets]} plus `worst_saturated_frac`, `worst_dark_frac`, `fails_on` (the lines
        crossed: "white", "black") and `passes`."""
        pc = self.cfg
        out: dict = {"starts": {}}
        for name, st in self.starts.items():
            rows = []
            for k in pc.offsets_ev:
                evs, clipped, dark = self._drive(controller, settings_at(st["agae_ref_ev"] + k), st["frame"])
                off = evs - st["agae_ref_ev"]
                rows.append({"k_ev": k, "start_offset_ev": float(off[0]),
                             "final_offset_ev": float(off[-pc.last_frames:].mean()),
                             "mean_step_first_ev": float((off[pc.first_frames] - off[0]) / pc.first_frames),
                             "final_saturated_frac": clipped, "final_dark_frac": dark,
                             "offset_ev": off.round(3).tolist()})
            out["starts"][name] = rows
        rows = [r for rows in out["starts"].values() for r in rows]
        out["worst_saturated_frac"] = worst = max(r["final_saturated_frac"] for r in rows)
        out["worst_dark_frac"] = darkest = max(r["final_dark_frac"] for r in rows)
        # which line a failing network crossed, so a log line can say whether it ends white or black
        out["fails_on"] = ((["white"] if worst >= pc.max_saturated_fraction else [])
                           + (["black"] if pc.max_dark_fraction is not None and darkest >= pc.max_dark_fraction
                              else []))
        out["passes"] = not out["fails_on"]
        return out


def make_probe(pcfg: ProbeConfig, world: "WorldConfig", rig: "RigConfig", sensor: "SensorConfig",
               agae_params: Any, project_root) -> SaturationProbe:
    """The probe for typed configs a stage built (its world, rig and sensor; `controllers.agae` as given) and its city.
    select_model passes its EvaluationInputs' groups, collect_iter its CollectInputs' ones."""
    from pathlib import Path

    from expoctl.controllers.registry import make_controller
    from expoctl.world import load_city

    if pcfg.city not in world.cities:
        raise ConfigError("select_model.probe.city", f"{pcfg.city!r} is not a world.cities entry ({sorted(world.cities)})")
    city_dir = world.city_dir if world.city_dir is not None else "conf/world/cities"
    city = load_city(world.cities[pcfg.city], str(Path(project_root) / city_dir))
    return SaturationProbe(pcfg, city, rig, world.render, sensor, make_controller("agae", agae_params))


@dataclass(frozen=True)
class ProbeJob:
    """One candidate's probe, for a worker (picklable): the typed configs `make_probe` takes and the candidate's
    `controllers.learned` keys with its checkpoint. The worker builds the probe (once per process and config) and
    the network itself."""

    pcfg: ProbeConfig
    world: "WorldConfig"
    rig: "RigConfig"
    sensor: "SensorConfig"
    agae_params: Any  # controllers.agae, typed (AgAeConfig)
    project_root: str
    name: str
    learned_params: Any  # controllers.learned, typed (LearnedConfig) with the candidate's checkpoint


_PROBES: dict[bytes, SaturationProbe] = {}  # per process: building a probe drives AG+AE, so each config builds once


def probe_job(job: ProbeJob) -> dict:
    """`SaturationProbe.run` of one candidate network (runs in a worker, or in process)."""
    import pickle

    from expoctl.controllers.registry import make_controller

    key = pickle.dumps((job.pcfg, job.world, job.rig, job.sensor, repr(job.agae_params), job.project_root))
    if key not in _PROBES:
        _PROBES.clear()
        _PROBES[key] = make_probe(job.pcfg, job.world, job.rig, job.sensor, job.agae_params, job.project_root)
    return _PROBES[key].run(make_controller("learned", job.learned_params))


def probe_all(probe: SaturationProbe, controllers: Mapping[str, Callable[[], Controller]]) -> dict[str, dict]:
    """Run the probe for each named controller factory (a fresh controller per name)."""
    return {name: probe.run(factory()) for name, factory in controllers.items()}


def verdict(result: dict) -> str:
    """'passes', or which fixed point made a probe result fail."""
    return "passes" if result["passes"] else f"FAILS ({' and '.join(result['fails_on'])} fixed point)"


def summary_line(name: str, result: dict) -> str:
    """One human-readable line: final offset / clipped / black share per start and offset, and the verdict."""
    cells = []
    for start, rows in result["starts"].items():
        cells.append(f"{start} " + ", ".join(f"{r['k_ev']:+g}→{r['final_offset_ev']:+.1f} EV "
                                             f"{100 * r['final_saturated_frac']:.0f} % white "
                                             f"{100 * r['final_dark_frac']:.0f} % black" for r in rows))
    return (f"{name}: " + "; ".join(cells) + f"; worst {100 * result['worst_saturated_frac']:.0f} % white, "
            f"{100 * result['worst_dark_frac']:.0f} % black: {verdict(result)}")
