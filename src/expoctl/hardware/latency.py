"""Actuation delay measured from the images themselves: exposure steps in front of a static scene.

Why: a camera without chunk data reports its settings by register read-back, which shows a command as soon as it is
written — so the delay `drive` measures from that metadata is a lower bound (`expoctl.hardware.base`). The image
cannot lie: command a step in exposure, and count the camera's frames until the image's brightness moves.

Per step (free-running, every frame taken, none skipped):
1. the newest frame k before the command sets the reference brightness (mean grey level);
2. the exposure is doubled or halved (alternately, within the usable limits), gain held;
3. frames k+1, k+2, … are read until the mean moves in the step's direction by more than `threshold` of the change
   a linear sensor would show (at least `min_levels` grey levels: clipping and the response curve make the real
   change smaller, mains flicker makes small ones meaningless), or `max_frames` pass. Delay = device frame number of that frame − k; the same for the
   first frame whose metadata (chunk or read-back) shows the command.
Needs a static, mid-grey scene that neither clips nor goes black at the stepped exposures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from expoctl.hardware.base import Camera, CameraError, Limits
from expoctl.hardware.live import same_settings
from expoctl.controllers.base import Settings


@dataclass(frozen=True)
class StepDelay:
    exposure_from_us: float
    exposure_to_us: float
    image_delay: int | None  # camera frames until the image's brightness moved (None: not within max_frames)
    metadata_delay: int | None  # camera frames until the metadata showed the command


def _mean(frame) -> float:
    return float(frame.image.mean())


def measure_delay(camera: Camera, limits: Limits, steps: int = 6, threshold: float = 0.1, min_levels: float = 3.0,
                  max_frames: int = 10, settle_frames: int = 5, timeout_s: float = 2.0) -> list[StepDelay]:
    """Exposure steps on a free-running camera (module doc); the camera must not be streaming yet."""
    now = limits.clamp(camera.read_settings())
    lo, hi = limits.exposure_us.low, limits.exposure_us.high
    if hi < 2.0 * lo:
        raise CameraError(f"camera {camera.camera_id}: its usable exposure range {limits.exposure_us} µs is too narrow "
                          "for a ×2 step")
    base = Settings(now.gain_db, float(min(max(now.exposure_us, 2.0 * lo), hi / 2.0)))  # room to step both ways
    camera.apply(base)
    camera.start(triggered=False)
    out: list[StepDelay] = []
    try:
        for _ in range(settle_frames):  # let the base settings reach the image
            camera.grab(timeout_s, newest=True)
        current = base
        for i in range(steps):
            ref, _ = camera.grab(timeout_s, newest=True)
            target_exposure = current.exposure_us * (2.0 if i % 2 == 0 else 0.5)
            target = camera.apply(Settings(current.gain_db, target_exposure))
            k = ref.device_frame_id
            m0 = _mean(ref)
            expected = m0 * (target.exposure_us / current.exposure_us - 1.0)  # a linear sensor: mean ∝ exposure
            needed = max(min_levels, threshold * abs(expected))
            image_delay = metadata_delay = None
            while image_delay is None or metadata_delay is None:
                frame, _ = camera.grab(timeout_s)
                n = frame.device_frame_id - k
                if n > max_frames:
                    break
                moved = _mean(frame) - m0
                if image_delay is None and math.copysign(1.0, moved) == math.copysign(1.0, expected) \
                        and abs(moved) > needed:
                    image_delay = n
                if metadata_delay is None and same_settings(frame.settings, target):
                    metadata_delay = n
            out.append(StepDelay(current.exposure_us, target.exposure_us, image_delay, metadata_delay))
            current = target
    finally:
        camera.stop()
    return out


def summarise(delays: list[StepDelay]) -> dict:
    img = [d.image_delay for d in delays if d.image_delay is not None]
    meta = [d.metadata_delay for d in delays if d.metadata_delay is not None]
    return {"steps": len(delays),
            "image_delay_frames": {"median": float(np.median(img)) if img else None, "values": img},
            "metadata_delay_frames": {"median": float(np.median(meta)) if meta else None, "values": meta},
            "steps_without_image_change": len(delays) - len(img)}
