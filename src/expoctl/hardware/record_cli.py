"""Record the paper's dual-camera training data on two real cameras (camera 1 reference, camera 2 perturbed).

  expoctl record --camera1 ID --camera2 ID --out DIR [--reference agae|learned] [--frames N] --baseline-m B

Camera 1 runs the reference controller; camera 2 gets camera 1's settings perturbed by the same code as the
simulated rig (`expoctl.sim.protocol`). Both cameras are software-triggered together for every frame pair, and each
pair's host receive times must agree within --pair-tolerance-ms. Without --frames it records until Ctrl-C; the
frames up to then are a complete raw sequence that `expoctl validate` and `ingest` accept.
"""

from __future__ import annotations

import argparse
import sys
from contextlib import ExitStack

from expoctl.hardware.cli_common import add_camera_options, check_numbers, describe, open_cameras
from expoctl.errors import InputError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from expoctl.hardware.session import camera_controller_names

    parser.add_argument("--camera1", required=True, help="reference camera id (device id, serial or IP address)")
    parser.add_argument("--camera2", required=True, help="perturbed camera id")
    parser.add_argument("--out", required=True, help="new sequence directory to write (never overwritten)")
    parser.add_argument("--reference", choices=camera_controller_names(), default="agae",
                        help="camera 1's controller (default agae; learned = the paper's second iteration)")
    parser.add_argument("--model", help="trained checkpoint for --reference learned")
    parser.add_argument("--model-backend", choices=("auto", "onnx", "torch"), default="auto")
    parser.add_argument("--frames", type=int, help="frame pairs to record (default: until Ctrl-C)")
    parser.add_argument("--warmup", type=int, default=30,
                        help="frames camera 1's controller runs before recording starts (default 30)")
    parser.add_argument("--baseline-m", type=float, required=True, help="distance between the two cameras, metres")
    parser.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                        help="camera 1's pinhole intrinsics in pixels at the recorded resolution (sequence.yaml "
                             "rig.intrinsics; evaluation's VO needs them, training does not)")
    parser.add_argument("--seed", type=int, default=0, help="seed of camera 2's perturbation draws (default 0)")
    parser.add_argument("--pair-tolerance-ms", type=float, default=10.0,
                        help="largest receive-time difference of a frame pair (default 10 ms; module doc of "
                             "expoctl.hardware.live)")
    add_camera_options(parser)


def run(args: argparse.Namespace) -> int:
    from expoctl.hardware import session

    check_numbers(args)
    problems = []
    if args.camera1 == args.camera2:
        problems.append(f"--camera1 and --camera2 are the same camera ({args.camera1})")
    if not args.baseline_m > 0:
        problems.append(f"--baseline-m must be a positive distance in metres, got {args.baseline_m}")
    if args.warmup < 0:
        problems.append(f"--warmup must be >= 0, got {args.warmup}")
    if args.intrinsics is not None and not (args.intrinsics[0] > 0 and args.intrinsics[1] > 0):
        problems.append(f"--intrinsics focal lengths FX FY must be positive, got {args.intrinsics[:2]}")
    if not args.pair_tolerance_ms > 0:
        problems.append(f"--pair-tolerance-ms must be positive, got {args.pair_tolerance_ms}")
    if problems:
        raise InputError("; ".join(problems))
    out = session.check_out_dir(args.out)
    with ExitStack() as stack:
        (cam1, lim1), (cam2, lim2) = open_cameras(stack, [args.camera1, args.camera2], args)
        params = session.controller_config(args.reference, lim1, args.model, args.model_backend)
        for cam, lim in ((cam1, lim1), (cam2, lim2)):
            print(describe(cam, lim))
        try:
            res = session.record((cam1, cam2), (lim1, lim2), args.reference, params, out, n_frames=args.frames,
                                 baseline_m=args.baseline_m, seed=args.seed, warmup_frames=args.warmup,
                                 pair_tolerance_ms=args.pair_tolerance_ms, timeout_s=args.timeout_s,
                                 intrinsics=None if args.intrinsics is None else
                                 dict(zip(("fx", "fy", "cx", "cy"), args.intrinsics)),
                                 report=lambda line: print(line, flush=True))
        except KeyboardInterrupt:
            print("expoctl record: aborted by a second interrupt; nothing was written", file=sys.stderr)
            return 130
    s = res.summary
    print(f"record: {res.n_frames} frame pairs ({res.stopped}), loop {s['loop_hz']} Hz; pair offset "
          f"{s['pair_offset_ms']['median']} ms median, {s['pair_offset_ms']['max']} ms max (tolerance "
          f"{args.pair_tolerance_ms:g} ms), {s['mispaired']} pairs re-triggered; camera frames dropped "
          f"{s['camera1']['dropped']} + {s['camera2']['dropped']}")
    print(f"sequence written to {res.out_dir}" if res.out_dir else "no frames recorded; nothing written")
    return 0
