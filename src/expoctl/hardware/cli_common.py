"""Command-line options shared by `expoctl drive` and `expoctl record`, and turning them into open cameras."""

from __future__ import annotations

import argparse
import math
from contextlib import ExitStack

from expoctl.hardware import BACKENDS, open_camera
from expoctl.hardware.base import Camera, CameraError, Limits, UserLimits, effective_limits
from expoctl.errors import InputError


def add_camera_options(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("camera (applies to every camera of the run)")
    g.add_argument("--backend", choices=BACKENDS, default="aravis", help="camera driver (default aravis)")
    g.add_argument("--width", type=int, help="image width in pixels, a region from the sensor's top-left corner "
                                             "(default: the camera's current region)")
    g.add_argument("--height", type=int, help="image height in pixels (default: the camera's current region)")
    g.add_argument("--pixel-format", help="GenICam pixel format: Mono8, RGB8, BGR8 or Bayer*8 (default: the camera's "
                                          "current if 8-bit, else a colour one)")
    g.add_argument("--fps", type=float, help="camera frame rate in Hz (default: the camera's current)")
    g.add_argument("--gain-db-per-raw", type=float,
                   help="dB per GainRaw step, for cameras without a Gain (dB) feature (the emulator: 6)")
    g.add_argument("--gain-min-db", type=float, help="lowest gain the controller may use (within the camera's range)")
    g.add_argument("--gain-max-db", type=float, help="highest gain the controller may use")
    g.add_argument("--exposure-min-us", type=float, help="shortest exposure the controller may use")
    g.add_argument("--exposure-max-us", type=float, help="longest exposure the controller may use")
    g.add_argument("--timeout-s", type=float, default=2.0,
                   help="a camera that sends no frame for this long is taken as lost (default 2 s)")


def check_numbers(args: argparse.Namespace) -> None:
    """Option values that are wrong whatever the camera: all reported at once."""
    problems = []
    for name in ("width", "height"):
        v = getattr(args, name)
        if v is not None and v <= 0:
            problems.append(f"--{name} must be a positive number of pixels, got {v}")
    for name in ("fps", "gain_db_per_raw", "timeout_s"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            problems.append(f"--{name.replace('_', '-')} must be a positive number, got {v}")
    frames = getattr(args, "frames", None)
    if frames is not None and frames < 1:
        problems.append(f"--frames must be at least 1, got {frames}")
    if problems:
        raise InputError("; ".join(problems))


def open_cameras(stack: ExitStack, ids: list[str], args: argparse.Namespace) -> list[tuple[Camera, Limits]]:
    """Open every camera (closed by `stack`) and work out its usable limits; every problem found is reported."""
    user = UserLimits(args.gain_min_db, args.gain_max_db, args.exposure_min_us, args.exposure_max_us)
    out, problems = [], []
    if len(ids) > 1 and args.backend == "aravis":  # one camera named twice (serial and address, say)
        from expoctl.hardware.aravis import list_cameras, resolve_camera_id

        found = list_cameras()
        resolved = {}
        for cid in ids:
            try:
                resolved[cid] = resolve_camera_id(cid, found)
            except CameraError as exc:
                problems.append(str(exc))
        if problems:
            raise CameraError("\n".join(problems))
        if len(set(resolved.values())) < len(ids):
            raise CameraError(f"{' and '.join(ids)} are the same camera ({next(iter(resolved.values()))}); "
                              "record needs two cameras")
    for cid in ids:
        try:
            cam = stack.enter_context(open_camera(cid, args.backend, width=args.width, height=args.height,
                                                  pixel_format=args.pixel_format, frame_rate_hz=args.fps,
                                                  gain_db_per_raw=args.gain_db_per_raw))
            out.append((cam, effective_limits(cid, cam.limits, user)))
        except CameraError as exc:
            problems.append(str(exc))
    if problems:
        raise CameraError("\n".join(problems))
    return out


def describe(cam: Camera, limits: Limits) -> str:
    i = cam.info
    return (f"{i.camera_id}: {i.model} serial {i.serial}, {i.resolution[0]}x{i.resolution[1]} {i.pixel_format}, "
            f"{i.frame_rate_hz or '?'} Hz; gain {limits.gain_db} dB via {i.features.get('gain')}, exposure "
            f"{limits.exposure_us} µs via {i.features.get('exposure')}; per-frame settings from {i.settings_source}")
