"""The camera interface every backend implements, and what is common to all of them.

A backend opens one physical camera by id and offers exactly what the closed loop needs:
- `limits`: the camera's own gain (dB) and exposure (µs) range, read from the device;
- `apply(settings)`: command gain and exposure (returns what the device accepted, after its own rounding);
- `grab()`: the next frame as 8-bit RGB, with the settings it was exposed with and its timestamp.

Where the settings of a frame come from (`Frame.settings_source`):
- "chunk": the camera's per-frame chunk data (ChunkExposureTime / ChunkGain) — what the sensor really used;
- "readback": the gain/exposure registers read right after the frame arrived. That is what the camera holds at that
  moment, not necessarily what the frame was exposed with: a command written while a frame is already being exposed
  shows in the register before it shows in an image. Actuation delays measured from read-back are therefore a lower
  bound (usually one frame); only chunk data measure the real delay.

Timestamps: `Frame.timestamp_ns` is the host's receive time, one clock for every camera on the machine (pairing two
cameras by it needs no clock synchronisation); `Frame.device_timestamp_ns` is the camera's own clock.

Bad input and device failures raise `CameraError` (an `InputError`): one message naming the camera and what is wrong.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import cv2
import numpy as np

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.controllers.base import Settings
from expoctl.errors import InputError

SETTINGS_SOURCES = ("chunk", "readback")


class CameraError(InputError):
    """A camera cannot be found, configured or read; the message names the camera."""


@dataclass(frozen=True)
class Range:
    low: float
    high: float

    def contains(self, v: float) -> bool:
        return self.low <= v <= self.high

    def clip(self, v: float) -> float:
        return float(min(max(v, self.low), self.high))

    def __str__(self) -> str:
        return f"{self.low:g}–{self.high:g}"


@dataclass(frozen=True)
class Limits:
    """A camera's gain range in dB and exposure range in µs."""

    gain_db: Range
    exposure_us: Range

    def clamp(self, s: Settings) -> Settings:
        return Settings(self.gain_db.clip(s.gain_db), self.exposure_us.clip(s.exposure_us))


#: what the library (controllers, network scaling, raw format) can represent: 0–30 dB, 75–30000 µs
LIBRARY_LIMITS = Limits(Range(GAIN_DB_MIN, GAIN_DB_MAX), Range(EXPOSURE_US_MIN, EXPOSURE_US_MAX))


@dataclass(frozen=True)
class UserLimits:
    """Optional user limits (CLI --gain-min-db …); None = the camera's (and the library's) own."""

    gain_min_db: float | None = None
    gain_max_db: float | None = None
    exposure_min_us: float | None = None
    exposure_max_us: float | None = None


def effective_limits(camera_id: str, camera: Limits, user: UserLimits = UserLimits(),
                     option_prefix: str = "--") -> Limits:
    """The range the loop may command: the camera's own range ∩ the library's ∩ the user's.

    Every user limit outside the camera's range (or the library's) is reported, all in one CameraError."""
    problems = []
    names = {"gain_min_db": "gain-min-db", "gain_max_db": "gain-max-db",
             "exposure_min_us": "exposure-min-us", "exposure_max_us": "exposure-max-us"}
    for key, value in vars(user).items():
        if value is None:
            continue
        cam_range = camera.gain_db if key.startswith("gain") else camera.exposure_us
        lib_range = LIBRARY_LIMITS.gain_db if key.startswith("gain") else LIBRARY_LIMITS.exposure_us
        unit = "dB" if key.startswith("gain") else "µs"
        opt = option_prefix + names[key]
        if not math.isfinite(value):
            problems.append(f"{opt} {value} is not a finite number")
        elif not cam_range.contains(value):
            problems.append(f"{opt} {value:g} {unit} is outside camera {camera_id}'s range {cam_range} {unit}")
        elif not lib_range.contains(value):
            problems.append(f"{opt} {value:g} {unit} is outside the range expoctl models and records ({lib_range} {unit})")
    g_lo = max(camera.gain_db.low, LIBRARY_LIMITS.gain_db.low, _or(user.gain_min_db, -math.inf))
    g_hi = min(camera.gain_db.high, LIBRARY_LIMITS.gain_db.high, _or(user.gain_max_db, math.inf))
    e_lo = max(camera.exposure_us.low, LIBRARY_LIMITS.exposure_us.low, _or(user.exposure_min_us, -math.inf))
    e_hi = min(camera.exposure_us.high, LIBRARY_LIMITS.exposure_us.high, _or(user.exposure_max_us, math.inf))
    if not problems:
        if g_lo > g_hi:
            problems.append(f"gain range is empty: camera {camera_id} has {camera.gain_db} dB, expoctl {LIBRARY_LIMITS.gain_db}"
                            f" dB, limits given [{_or(user.gain_min_db, '-')}, {_or(user.gain_max_db, '-')}]")
        if e_lo > e_hi:
            problems.append(f"exposure range is empty: camera {camera_id} has {camera.exposure_us} µs, expoctl "
                            f"{LIBRARY_LIMITS.exposure_us} µs, limits given [{_or(user.exposure_min_us, '-')}, "
                            f"{_or(user.exposure_max_us, '-')}]")
    if problems:
        raise CameraError(f"camera {camera_id}: " + "; ".join(problems))
    return Limits(Range(g_lo, g_hi), Range(e_lo, e_hi))


def _or(v, default):
    return default if v is None else v


@dataclass(frozen=True)
class Frame:
    """One image from a camera with what the camera says about it."""

    image: np.ndarray  # H×W×3 uint8 RGB
    settings: Settings  # what the frame was exposed with (see settings_source)
    settings_source: str  # "chunk" | "readback" (module doc)
    timestamp_ns: int  # host receive time (one clock for all cameras)
    device_timestamp_ns: int  # the camera's own clock
    device_frame_id: int  # the camera's frame counter (gaps = frames the camera sent but we never got)


@dataclass
class CameraInfo:
    """What sequence.yaml records about a camera (and `drive`/`record` print)."""

    camera_id: str
    backend: str
    model: str = ""
    serial: str = ""
    pixel_format: str = ""
    resolution: tuple[int, int] = (0, 0)  # (width, height)
    frame_rate_hz: float | None = None
    features: dict = field(default_factory=dict)  # which GenICam features carry gain/exposure, and their units
    settings_source: str = "readback"

    def to_dict(self) -> dict:
        return {"id": self.camera_id, "backend": self.backend, "model": self.model, "serial": self.serial,
                "pixel_format": self.pixel_format, "resolution": list(self.resolution),
                "frame_rate_hz": self.frame_rate_hz, "features": dict(self.features),
                "settings_source": self.settings_source}


class Camera(ABC):
    """One open camera. Use as a context manager so it is always released."""

    info: CameraInfo
    limits: Limits  # the camera's own range (before the library's and the user's limits)

    @property
    def camera_id(self) -> str:
        return self.info.camera_id

    @abstractmethod
    def read_settings(self) -> Settings:
        """The gain and exposure the camera holds now (its registers)."""

    @abstractmethod
    def apply(self, settings: Settings) -> Settings:
        """Command gain and exposure; return the values the device holds afterwards (its rounding applied)."""

    @abstractmethod
    def start(self, triggered: bool) -> None:
        """Start streaming: free-running at the camera's frame rate, or one frame per `trigger()`."""

    @abstractmethod
    def trigger(self) -> None:
        """Software trigger: expose one frame now (only after `start(triggered=True)`)."""

    @abstractmethod
    def grab(self, timeout_s: float, newest: bool = False) -> tuple[Frame, int]:
        """The next frame (with `newest`, the newest one queued, older ones are discarded) and the number of frames
        discarded. CameraError if none arrives within `timeout_s` (a camera that disappeared) or the camera is lost."""

    @abstractmethod
    def discard_queued(self) -> int:
        """Drop every frame already received but not yet grabbed (before a trigger: so the next frame grabbed is the
        one that trigger exposed); returns how many were dropped."""

    @abstractmethod
    def stop(self) -> None:
        """Stop streaming (idempotent)."""

    @abstractmethod
    def close(self) -> None:
        """Stop and release the device (idempotent, never raises)."""

    def __enter__(self) -> "Camera":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- pixel formats --------------------------------------------------------------------------------------------------

#: GenICam PFNC 8-bit Bayer formats → OpenCV's demosaicing code named by the same 2×2 tile (R G / G B = RGGB)
_BAYER_TO_RGB = {
    "BayerRG8": cv2.COLOR_BayerRGGB2RGB,
    "BayerGR8": cv2.COLOR_BayerGRBG2RGB,
    "BayerGB8": cv2.COLOR_BayerGBRG2RGB,
    "BayerBG8": cv2.COLOR_BayerBGGR2RGB,
}
SUPPORTED_PIXEL_FORMATS = ("Mono8", "RGB8", "BGR8", "RGB8Packed", "BGR8Packed", *_BAYER_TO_RGB)


def to_rgb8(data: bytes | np.ndarray, width: int, height: int, pixel_format: str) -> np.ndarray:
    """A raw 8-bit camera buffer → H×W×3 uint8 RGB (what the raw format and the controllers take).

    Mono8: the grey value in all three channels (the network sees a grey image, like a colour camera in a grey
    world). Bayer*8: bilinear demosaicing (OpenCV), no white balance — the camera's own colour response is what the
    data should record. RGB8/BGR8: as delivered (BGR reordered). Other formats raise ValueError (the backend turns it
    into a CameraError naming the camera and the formats it could use instead)."""
    buf = np.frombuffer(data, dtype=np.uint8) if not isinstance(data, np.ndarray) else data.reshape(-1)
    channels = 3 if pixel_format in ("RGB8", "BGR8", "RGB8Packed", "BGR8Packed") else 1
    if pixel_format not in SUPPORTED_PIXEL_FORMATS:
        raise ValueError(f"pixel format {pixel_format} is not supported (use one of {', '.join(SUPPORTED_PIXEL_FORMATS)})")
    need = width * height * channels
    if buf.size < need:
        raise ValueError(f"{pixel_format} buffer of {buf.size} bytes is too short for {width}x{height} ({need} bytes)")
    img = buf[:need].reshape(height, width, channels) if channels == 3 else buf[:need].reshape(height, width)
    if pixel_format == "Mono8":
        return np.ascontiguousarray(np.repeat(img[:, :, None], 3, axis=2))
    if pixel_format in _BAYER_TO_RGB:
        return cv2.cvtColor(img, _BAYER_TO_RGB[pixel_format])
    if pixel_format.startswith("BGR"):
        return np.ascontiguousarray(img[:, :, ::-1])
    return np.ascontiguousarray(img)
