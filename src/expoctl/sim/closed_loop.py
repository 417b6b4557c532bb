"""Closed loop: one or two simulated cameras driven frame by frame by controllers.

Order of events at frame t (one frame of actuation latency, docs/pipeline.md, Conventions that hold everywhere):
  1. each camera captures frame t with the settings it was given for t;
  2. camera 1's controller sees (image_t, settings_t) and returns the settings for t+1;
  3. camera 2's settings for t+1 are either the perturbation of camera 1's settings for t+1 (the paper's
     data-collection protocol) or what camera 2's own controller returns (two controllers side by side).
So nothing computed from frame t can change frame t itself — the loop enforces it, controllers cannot break it.

The loop itself (`drive_rig`) knows nothing of where frames come from: a `Rig` captures one frame per camera with
the settings it is given and reports the settings each frame was actually exposed with. The simulator's rig
(`SimRig`: scene + sensors) reports exactly what it was given; a real camera rig (`expoctl.hardware.live.LiveRig`)
reports what the camera's metadata says, which may lag the command. Controllers always see the reported settings.

Randomness: sensor noise for (camera c, frame t) comes from a generator seeded by (seed, c, t), so a frame's
noise does not depend on how many frames ran before it (warm-up length, process) and reruns are bit-identical.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterator, Protocol, Sequence

import numpy as np

from expoctl.config_reader import Problems, Section
from expoctl.controllers.base import Controller, Settings
from expoctl.sim.protocol import PerturbationConfig, perturb
from expoctl.world.render_config import RenderConfig

if TYPE_CHECKING:
    from expoctl.camera.sensor import SensorConfig

#: stream id mixed into per-frame sensor seeds (the perturbation uses a different one)
_SENSOR_STREAM = 0x5E4


class Scene(Protocol):
    """What the loop needs from the world: scene luminance for a frame, an exposure and a camera."""

    def luminance(self, frame_index: int, exposure_us: float, camera: int) -> np.ndarray:
        """H×W×3 float32 luminance in cd/m² seen by `camera` (1 or 2) over the exposure interval of `frame_index`."""

    def timestamp_ns(self, frame_index: int) -> int:
        """Capture time of `frame_index` in nanoseconds."""


class SensorLike(Protocol):
    def capture(self, luminance_cd_m2: np.ndarray, exposure_us: float, gain_db: float, rng: np.random.Generator) -> np.ndarray:
        """8-bit RGB image of the luminance at these settings."""


@dataclass(frozen=True)
class CameraFrame:
    camera: int
    settings: Settings  # what the frame was exposed with (simulator: the command; real camera: its metadata)
    image: np.ndarray  # H×W×3 uint8 RGB
    timestamp_ns: int | None = None  # this camera's own capture time, when it differs from the rig frame's


@dataclass(frozen=True)
class RigFrame:
    frame_index: int
    timestamp_ns: int
    cameras: tuple[CameraFrame, ...]

    def camera(self, c: int) -> CameraFrame:
        return self.cameras[c - 1]


def sensor_rng(seed: int, camera: int, frame_index: int) -> np.random.Generator:
    """The generator for one camera's sensor noise at one frame."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), _SENSOR_STREAM, int(camera), int(frame_index)]))


class Rig(Protocol):
    """What `drive_rig` drives: cameras 1 (and 2) that capture one frame each per frame index."""

    def capture(self, frame_index: int, settings: Sequence[Settings]) -> RigFrame:
        """Capture `frame_index` on cameras 1..len(settings), camera c with settings[c − 1]; the RigFrame's camera
        frames carry the settings each image was actually exposed with."""


class SimRig:
    """The simulated rig: a scene seen through one or two sensors, with per-(camera, frame) noise seeds."""

    def __init__(self, scene: Scene, sensors: Sequence[SensorLike], seed: int):
        self.scene, self.sensors, self.seed = scene, list(sensors), int(seed)

    def capture(self, frame_index: int, settings: Sequence[Settings]) -> RigFrame:
        cams = tuple(CameraFrame(c, s, _capture(self.scene, self.sensors[c - 1], c, frame_index, s, self.seed))
                     for c, s in enumerate(settings, start=1))
        return RigFrame(frame_index, int(self.scene.timestamp_ns(frame_index)), cams)


def run_closed_loop(
    scene: Scene,
    sensors: Sequence[SensorLike],
    controller: Controller,
    initial: Settings,
    frames: range,
    seed: int,
    *,
    perturbation: PerturbationConfig | None = None,
    camera2_controller: Controller | None = None,
    camera2_initial: Settings | None = None,
    warmup_frames: int = 0,
) -> Iterator[RigFrame]:
    """Drive the simulated rig over `frames` (frame indices of the scene, step 1) and yield one `RigFrame` per frame.

    One sensor: camera 1 only (evaluation). Two sensors: camera 2 follows camera 1 through `perturbation`
    (data collection) or runs `camera2_controller` (side-by-side comparison) — exactly one of the two.
    `warmup_frames` frames before `frames.start` (as many as exist) run camera 1's controller without being
    yielded, so the reference controller has settled like a rig that was already running.
    """
    if len(sensors) not in (1, 2):
        raise ValueError(f"the rig has one or two cameras, got {len(sensors)} sensors")
    return drive_rig(SimRig(scene, sensors, seed), len(sensors), controller, initial, frames, seed,
                     perturbation=perturbation, camera2_controller=camera2_controller,
                     camera2_initial=camera2_initial, warmup_frames=warmup_frames)


def drive_rig(
    rig: Rig,
    n_cameras: int,
    controller: Controller,
    initial: Settings,
    frames: range,
    seed: int,
    *,
    perturbation: PerturbationConfig | None = None,
    camera2_controller: Controller | None = None,
    camera2_initial: Settings | None = None,
    warmup_frames: int = 0,
    limit: Callable[[int, Settings], Settings] | None = None,
) -> Iterator[RigFrame]:
    """The closed loop over any `Rig` (simulated or real) — the one copy of the order of events in the module doc.

    `limit(camera, settings)` further restricts commands to a camera's own range (a real camera's limits); the
    library's ranges always apply. Camera 2's perturbation is computed from camera 1's (limited) command, as in the
    simulator, and then limited to camera 2's own range.
    """
    if frames.step != 1:
        raise ValueError(f"frames must be consecutive (step 1), got {frames}")
    if n_cameras not in (1, 2):
        raise ValueError(f"the rig has one or two cameras, got {n_cameras}")
    two = n_cameras == 2
    if two and (perturbation is None) == (camera2_controller is None):
        raise ValueError("with two cameras give exactly one of `perturbation` or `camera2_controller`")
    if not two and (perturbation is not None or camera2_controller is not None):
        raise ValueError("camera-2 options given but only one camera")
    lim = limit or (lambda _camera, s: s)

    first = max(0, frames.start - max(0, int(warmup_frames)))
    settings1 = lim(1, initial.clamped())
    controller.reset(settings1)
    for t in range(first, frames.start):  # warm-up: camera 1 only, nothing recorded
        cam1 = rig.capture(t, (settings1,)).camera(1)
        settings1 = lim(1, _next_settings(controller, cam1.image, cam1.settings, t))

    settings2: Settings | None = None
    if two:
        if camera2_controller is not None:
            settings2 = lim(2, (camera2_initial or settings1).clamped())
            camera2_controller.reset(settings2)
        else:
            settings2 = lim(2, perturb(settings1, frames.start, seed, perturbation))

    for t in frames:
        frame = rig.capture(t, (settings1, settings2) if two else (settings1,))
        yield frame
        # settings computed from frame t take effect at t+1; controllers see what each frame was exposed with
        cam1 = frame.camera(1)
        settings1 = lim(1, _next_settings(controller, cam1.image, cam1.settings, t))
        if two:
            cam2 = frame.camera(2)
            if camera2_controller is not None:
                settings2 = lim(2, _next_settings(camera2_controller, cam2.image, cam2.settings, t))
            else:
                settings2 = lim(2, perturb(settings1, t + 1, seed, perturbation))


def _capture(scene: Scene, sensor: SensorLike, camera: int, t: int, settings: Settings, seed: int) -> np.ndarray:
    luminance = scene.luminance(t, settings.exposure_us, camera)
    return sensor.capture(luminance, settings.exposure_us, settings.gain_db, sensor_rng(seed, camera, t))


def _next_settings(controller: Controller, image: np.ndarray, applied: Settings, t: int) -> Settings:
    nxt = controller.update(image, applied)
    if not (math.isfinite(nxt.gain_db) and math.isfinite(nxt.exposure_us)):
        raise ValueError(f"controller {controller.name!r} returned non-finite settings {nxt} at frame {t}")
    return nxt.clamped()


class FunctionScene:
    """A `Scene` from plain functions (tests, image-based scenes): luminance_fn(frame, exposure_us, camera)."""

    def __init__(
        self,
        luminance_fn: Callable[[int, float, int], np.ndarray],
        fps: float,
        t0_ns: int = 0,
    ):
        self._fn = luminance_fn
        self._period_ns = 1e9 / fps
        self._t0_ns = int(t0_ns)

    def luminance(self, frame_index: int, exposure_us: float, camera: int) -> np.ndarray:
        return self._fn(frame_index, exposure_us, camera)

    def timestamp_ns(self, frame_index: int) -> int:
        return self._t0_ns + int(round(frame_index * self._period_ns))


# --- the simulated rig: config, world scene, sensors ---------------------------------------------------------------


@dataclass(frozen=True)
class RigConfig:
    """The dual-camera rig (config group `rig`): geometry, frame rate and camera 2's perturbation.
    Image size and field of view are the world renderer's (`world.render`), shared by every stage."""

    baseline_m: float = 0.0392
    fps: float = 15.0
    perturbation: PerturbationConfig = PerturbationConfig()

    @classmethod
    def from_dict(cls, d: Any, key: str = "rig", problems: Problems | None = None) -> "RigConfig":
        r = Section(d, key, problems)
        baseline, fps = r.number("baseline_m", cls.baseline_m, above=0), r.number("fps", cls.fps, above=0)
        perturbation = PerturbationConfig.from_dict(r.value("perturbation", None), r.path("perturbation"), r.problems)
        r.done()
        return cls(baseline, fps, perturbation)


def rig_metadata(rig: RigConfig, render: RenderConfig) -> dict:
    """The `rig` block of sequence.yaml: baseline_m, fps, resolution [w, h], intrinsics {fx, fy, cx, cy}, hfov_deg."""
    from expoctl.world import intrinsics

    k = np.asarray(intrinsics(render.width, render.height, render.hfov_deg), dtype=np.float64)
    return {
        "baseline_m": rig.baseline_m,
        "fps": rig.fps,
        "resolution": [render.width, render.height],
        "intrinsics": {"fx": float(k[0, 0]), "fy": float(k[1, 1]), "cx": float(k[0, 2]), "cy": float(k[1, 2])},
        "hfov_deg": render.hfov_deg,
    }


class RouteScene:
    """A `Scene` of the simulated world: a city's trajectory rendered for camera 1 (at the rig origin) and camera 2
    (`baseline_m` to its right, along the camera x axis), with motion blur over each camera's own exposure."""

    def __init__(self, city, trajectory, rig: RigConfig, render: RenderConfig):
        self.trajectory = trajectory
        from expoctl.world.backends import make_renderer

        self.renderer = make_renderer(city, render)
        self._city, self._render = city, render
        self._coarse: dict[int, object] = {}  # factor → renderer at 1/factor of the size (luminance_coarse)
        self._offset_m = {1: 0.0, 2: rig.baseline_m}

    def luminance(self, frame_index: int, exposure_us: float, camera: int) -> np.ndarray:
        return self.renderer.render_exposure(self.trajectory, frame_index, exposure_us, self._offset_m[camera])

    def luminance_coarse(self, frame_index: int, exposure_us: float, camera: int, factor: int) -> np.ndarray:
        """The same exposure rendered at 1/`factor` of the width and height (same field of view and physics, one
        ray per coarse pixel): (H/factor, W/factor, 3) cd/m². The oracle scores its candidates at its matching size
        with these (controllers.oracle.candidate_render)."""
        from dataclasses import replace

        from expoctl.world.backends import make_renderer

        factor = int(factor)
        w, h = self._render.width, self._render.height
        if factor < 2 or w % factor or h % factor:
            raise ValueError(f"coarse factor {factor} does not divide the {w}x{h} render")
        if factor not in self._coarse:
            self._coarse[factor] = make_renderer(self._city, replace(self._render, width=w // factor,
                                                                     height=h // factor))
        return self._coarse[factor].render_exposure(self.trajectory, frame_index, exposure_us,
                                                    self._offset_m[camera])

    def timestamp_ns(self, frame_index: int) -> int:
        return int(self.trajectory.timestamps_ns[frame_index])


def make_sensors(base: "SensorConfig", render: RenderConfig, n_cameras: int, randomisation: float, seed: int):
    """`n_cameras` identical sensors — one parameter set (`base`, config group `sensor`), randomised by
    ±`randomisation` from `seed` (the rig's two cameras are the same model) but each camera its own fixed-pattern
    noise — and the set as a dict for sequence.yaml."""
    from expoctl.camera.sensor import Sensor

    rng = np.random.default_rng(np.random.SeedSequence([int(seed), _SENSOR_STREAM, 0xC0F]))
    config = base.randomised(rng, randomisation) if randomisation > 0 else base
    sensors = [Sensor(config, render.height, render.width, seed=_sensor_unit_seed(seed, c)) for c in range(1, n_cameras + 1)]
    return sensors, _config_dict(config)


def clip_sections(sections: Sequence[dict], start: int, stop: int) -> list[dict]:
    """Sections of trajectory frames [start, stop) re-indexed to the window (end_frame inclusive, as in the world)."""
    out = []
    for s in sections:
        a, b = max(int(s["start_frame"]), start), min(int(s["end_frame"]), stop - 1)
        if a <= b:
            out.append({"start_frame": a - start, "end_frame": b - start, "kind": str(s["kind"])})
    return out


def _sensor_unit_seed(seed: int, camera: int) -> int:
    return int(np.random.SeedSequence([int(seed), _SENSOR_STREAM, 0xF1D, camera]).generate_state(1)[0])


def _config_dict(config) -> dict:
    if hasattr(config, "to_dict"):
        return config.to_dict()
    import dataclasses

    return dataclasses.asdict(config)
