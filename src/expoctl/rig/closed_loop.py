"""Closed loop: one or two simulated cameras driven frame by frame by controllers.

Order of events at frame t (one frame of actuation latency, DESIGN "decisions that hold everywhere"):
  1. each camera captures frame t with the settings it was given for t;
  2. camera 1's controller sees (image_t, settings_t) and returns the settings for t+1;
  3. camera 2's settings for t+1 are either the perturbation of camera 1's settings for t+1 (the paper's
     data-collection protocol) or what camera 2's own controller returns (two controllers side by side).
So nothing computed from frame t can change frame t itself — the loop enforces it, controllers cannot break it.

Randomness: sensor noise for (camera c, frame t) comes from a generator seeded by (seed, c, t), so a frame's
noise does not depend on how many frames ran before it (warm-up length, process) and reruns are bit-identical.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Iterator, Protocol, Sequence

import numpy as np

from expoctl.controllers.base import Controller, Settings
from expoctl.rig.protocol import PerturbationConfig, perturb

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
    settings: Settings
    image: np.ndarray  # H×W×3 uint8 RGB


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
    """Drive the rig over `frames` (frame indices of the scene, step 1) and yield one `RigFrame` per frame.

    One sensor: camera 1 only (evaluation). Two sensors: camera 2 follows camera 1 through `perturbation`
    (data collection) or runs `camera2_controller` (side-by-side comparison) — exactly one of the two.
    `warmup_frames` frames before `frames.start` (as many as exist) run camera 1's controller without being
    yielded, so the reference controller has settled like a rig that was already running.
    """
    if frames.step != 1:
        raise ValueError(f"frames must be consecutive (step 1), got {frames}")
    if len(sensors) not in (1, 2):
        raise ValueError(f"the rig has one or two cameras, got {len(sensors)} sensors")
    two = len(sensors) == 2
    if two and (perturbation is None) == (camera2_controller is None):
        raise ValueError("with two cameras give exactly one of `perturbation` or `camera2_controller`")
    if not two and (perturbation is not None or camera2_controller is not None):
        raise ValueError("camera-2 options given but only one sensor")

    first = max(0, frames.start - max(0, int(warmup_frames)))
    settings1 = initial.clamped()
    controller.reset(settings1)
    for t in range(first, frames.start):  # warm-up: camera 1 only, nothing recorded
        image = _capture(scene, sensors[0], 1, t, settings1, seed)
        settings1 = _next_settings(controller, image, settings1, t)

    settings2: Settings | None = None
    if two:
        if camera2_controller is not None:
            settings2 = (camera2_initial or settings1).clamped()
            camera2_controller.reset(settings2)
        else:
            settings2 = perturb(settings1, frames.start, seed, perturbation)

    for t in frames:
        image1 = _capture(scene, sensors[0], 1, t, settings1, seed)
        cams = [CameraFrame(1, settings1, image1)]
        if two:
            image2 = _capture(scene, sensors[1], 2, t, settings2, seed)
            cams.append(CameraFrame(2, settings2, image2))
        yield RigFrame(t, int(scene.timestamp_ns(t)), tuple(cams))
        # settings computed from frame t take effect at t+1
        settings1 = _next_settings(controller, image1, settings1, t)
        if two:
            if camera2_controller is not None:
                settings2 = _next_settings(camera2_controller, image2, settings2, t)
            else:
                settings2 = perturb(settings1, t + 1, seed, perturbation)


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
