"""The one interface every gain/exposure controller implements.

A controller sees exactly what a real one sees: the 8-bit RGB image the camera delivered at frame t and the
settings that frame was captured with (what the controller commanded earlier). It returns the settings it
commands next; the camera applies them at frame t+1 (one frame of actuation latency, enforced by the caller,
`expoctl.sim.closed_loop`). Controllers with extra internal latency (AG+AE) model it themselves.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from expoctl.camera.ranges import clamp_settings
from expoctl.config_reader import Section, is_integer


@dataclass(frozen=True)
class Settings:
    """Camera settings: analogue gain in dB and exposure time in microseconds."""

    gain_db: float
    exposure_us: float

    def clamped(self) -> "Settings":
        g, e = clamp_settings(self.gain_db, self.exposure_us)
        return Settings(g, e)


class Controller(ABC):
    """Closed-loop gain/exposure controller."""

    #: short name used in reports and metrics.json (agae, shin, shim, mean_intensity, fixed, learned, oracle)
    name: str = "controller"

    @abstractmethod
    def reset(self, initial: Settings) -> None:
        """Start a new sequence; `initial` are the settings of the first frame."""

    @abstractmethod
    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        """Take frame t (H×W×3 uint8 RGB) and the settings it was captured with; return the settings for t+1."""


class TimedController(Controller):
    """Delegates to a controller and records how long each `update` takes (ms): evaluation's per-frame timing and
    the live camera loop's (`expoctl drive`)."""

    def __init__(self, inner: Controller):
        self.inner = inner
        self.name = inner.name
        self.update_ms: list[float] = []

    def reset(self, initial: Settings) -> None:
        self.inner.reset(initial)

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        t0 = time.perf_counter()
        out = self.inner.update(image, applied)
        self.update_ms.append((time.perf_counter() - t0) * 1e3)
        return out


#: A command computed from frame t exposes frame t + 1 at the earliest (nothing changes the frame it was computed
#: from), so a latency counts at least one frame.
LATENCY_FRAMES_MIN = 1


def read_latency_frames(section: Section) -> int:
    """The `latency_frames` key of a config section (`controllers.learned`, `labels`, which follows it): the one
    definition of its type, default and bounds."""
    return section.integer("latency_frames", 1, min=LATENCY_FRAMES_MIN)


class DelayedController(Controller):
    """Delegates to a controller whose commands land `latency_frames` frames after the frame they were computed from.

    The simulated rig applies a command at t+1 (`expoctl.sim.closed_loop`); a real camera's pipeline may need longer
    (the calibrated camera: t+2 at the earliest, docs/calibration.md). This holds each command back by
    `latency_frames − 1` frames, so the settings computed from frame t expose frame t + `latency_frames`. Until the
    first command lands, the camera keeps the initial settings. The inner controller sees every frame with the
    settings it was actually exposed with, as a real controller would. Use it in the simulator only: on a real
    camera the camera's own pipeline supplies the latency.
    """

    def __init__(self, inner: Controller, latency_frames: int):
        if not is_integer(latency_frames) or latency_frames < LATENCY_FRAMES_MIN:
            raise ValueError(f"latency_frames must be an integer >= {LATENCY_FRAMES_MIN}, got {latency_frames!r}")
        self.inner = inner
        self.name = inner.name
        self.latency_frames = latency_frames
        self._pending: list[Settings] = []

    def reset(self, initial: Settings) -> None:
        self.inner.reset(initial)
        # the commands already "in flight" when the sequence starts: the initial settings
        self._pending = [initial] * (self.latency_frames - 1)

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        self._pending.append(self.inner.update(image, applied))
        return self._pending.pop(0)
