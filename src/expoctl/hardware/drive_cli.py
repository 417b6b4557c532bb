"""Drive one real camera in closed loop with a controller, record what it saw, print per-frame timing.

  expoctl drive --camera ID --controller agae|fixed|learned [--model models/controller.pt] --frames N --out DIR

Writes a one-camera raw sequence (sequence.yaml `cameras: 1`) that `expoctl validate` accepts. Per frame it prints
the settings the frame was exposed with, its mean grey level, the controller's time on the previous frame, and the
actuation delay whenever a command first shows in a frame's metadata (camera frames from the frame the command was
computed on; 1 = the next frame).
"""

from __future__ import annotations

import argparse
import sys
from contextlib import ExitStack

from expoctl.hardware.cli_common import add_camera_options, check_numbers, describe, open_cameras


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from expoctl.hardware.session import camera_controller_names

    parser.add_argument("--camera", required=True, help="camera id: Aravis device id, serial number or IP address")
    parser.add_argument("--controller", required=True, choices=camera_controller_names())
    parser.add_argument("--model", help="trained checkpoint (models/controller.pt) for --controller learned; the "
                                        "ONNX export beside it is used when present")
    parser.add_argument("--model-backend", choices=("auto", "onnx", "torch"), default="auto",
                        help="network runtime (default: onnx if models/controller.onnx exists), 1 thread")
    parser.add_argument("--frames", type=int, required=True, help="number of frames to record")
    parser.add_argument("--out", required=True, help="new sequence directory to write (never overwritten)")
    parser.add_argument("--initial-gain-db", type=float, help="first frame's gain (default: the camera's current)")
    parser.add_argument("--initial-exposure-us", type=float, help="first frame's exposure (default: the camera's current)")
    add_camera_options(parser)


def run(args: argparse.Namespace) -> int:
    from expoctl.hardware import session
    from expoctl.controllers.base import Settings

    check_numbers(args)
    out = session.check_out_dir(args.out)
    with ExitStack() as stack:
        [(cam, limits)] = open_cameras(stack, [args.camera], args)
        params = session.controller_config(args.controller, limits, args.model, args.model_backend)
        initial = None
        if args.initial_gain_db is not None or args.initial_exposure_us is not None:
            now = cam.read_settings()
            initial = Settings(now.gain_db if args.initial_gain_db is None else args.initial_gain_db,
                               now.exposure_us if args.initial_exposure_us is None else args.initial_exposure_us)
        print(describe(cam, limits))
        try:
            res = session.drive(cam, limits, args.controller, params, out, args.frames, initial=initial,
                                timeout_s=args.timeout_s, report=lambda line: print(line, flush=True))
        except KeyboardInterrupt:
            print("expoctl drive: aborted by a second interrupt; nothing was written", file=sys.stderr)
            return 130
    s = res.summary
    ms, delay = s["controller_ms"], s["actuation_delay_frames"]
    source = s["settings_source"]
    if s["actuation_delays_measured"]:
        lag = (f"actuation delay {delay['median']:g} camera frames median (max {delay['max']:g}) over "
               f"{s['actuation_delays_measured']} setting changes, from {source}"
               f"{' (register read-back: a lower bound, see expoctl.hardware.base)' if source == 'readback' else ''}")
    else:
        lag = "actuation delay not measured (no setting change large enough to see)"
    print(f"drive: {res.n_frames} frames ({res.stopped}), loop {s['loop_hz']} Hz; controller {ms['median']} ms median, "
          f"{ms['p95']} ms p95; {lag}; camera frames dropped {s['dropped']}, skipped as stale {s['skipped_stale']}")
    print(f"sequence written to {res.out_dir}" if res.out_dir else "no frames recorded; nothing written")
    return 0
