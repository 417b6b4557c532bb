"""Measure a camera's actuation delay from its images: exposure steps in front of a static, mid-grey scene.

  expoctl latency --camera ID [--steps 6]

Per step it prints after how many camera frames the image's brightness moved and after how many the frame's
metadata (chunk data or register read-back) showed the new exposure; with read-back the second is only a lower
bound (expoctl.hardware.latency).
"""

from __future__ import annotations

import argparse
import json
from contextlib import ExitStack

from expoctl.hardware.cli_common import add_camera_options, check_numbers, describe, open_cameras
from expoctl.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--camera", required=True, help="camera id: Aravis device id, serial number or IP address")
    parser.add_argument("--steps", type=int, default=6, help="exposure steps (×2, ÷2 alternately; default 6)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON line at the end")
    add_camera_options(parser)


def run(args: argparse.Namespace) -> int:
    from expoctl.hardware.latency import measure_delay, summarise

    check_numbers(args)
    if args.steps < 1:
        raise InputError(f"--steps must be at least 1, got {args.steps}")
    with ExitStack() as stack:
        [(cam, limits)] = open_cameras(stack, [args.camera], args)
        print(describe(cam, limits))
        delays = measure_delay(cam, limits, steps=args.steps, timeout_s=args.timeout_s)
    print(f"{'step':>4} {'exposure_us':>21} {'image_frames':>12} {'metadata_frames':>15}")
    for i, d in enumerate(delays):
        print(f"{i:4d} {d.exposure_from_us:9.0f} → {d.exposure_to_us:9.0f} {d.image_delay if d.image_delay is not None else '-':>12} "
              f"{d.metadata_delay if d.metadata_delay is not None else '-':>15}")
    s = summarise(delays)
    print(f"latency: image moved after {s['image_delay_frames']['median']} camera frames (median of "
          f"{len(s['image_delay_frames']['values'])} steps), metadata ({cam.info.settings_source}) after "
          f"{s['metadata_delay_frames']['median']}")
    if args.json:
        print(json.dumps({"camera": cam.info.camera_id, "settings_source": cam.info.settings_source, **s}))
    return 0 if s["image_delay_frames"]["values"] else 1
