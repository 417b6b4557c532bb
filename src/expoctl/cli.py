"""`expoctl` command line (for people; DVC runs the stages/ modules).

  expoctl validate RAW_DIR                       check raw dual-camera sequences, one line per problem
  expoctl match --frontend orb|viso PREV CUR     feature and inlier counts of one image pair, one JSON line
  expoctl preview ...                            render a route under a controller to a contact sheet / video
  expoctl drive --camera ID --controller NAME ...  drive a real camera in closed loop, record it, print timing
  expoctl record --camera1 ID --camera2 ID ...   record dual-camera training data on two real cameras
  expoctl cameras                                list the cameras found (ids for --camera)
  expoctl latency --camera ID                    a camera's actuation delay, measured from its images
  expoctl bench [--controller NAME|module:Class]  score controllers on the benchmark routes: a leaderboard

Each subcommand lives in a module exposing `add_arguments(parser)` and `run(args) -> int`.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from expoctl.errors import InputError

SUBCOMMANDS = {
    "validate": ("expoctl.raw.validate_cli", "check raw dual-camera sequences"),
    "match": ("expoctl.features.match_cli", "count features and inlier matches of one image pair"),
    "preview": ("expoctl.sim.preview", "render a route under a controller to a contact sheet"),
    "drive": ("expoctl.hardware.drive_cli", "drive a real camera in closed loop with a controller"),
    "record": ("expoctl.hardware.record_cli", "record dual-camera training data on two real cameras"),
    "cameras": ("expoctl.hardware.list_cli", "list the cameras found"),
    "latency": ("expoctl.hardware.latency_cli", "measure a camera's actuation delay from its images"),
    "bench": ("expoctl.bench.cli", "score a controller on the benchmark routes against the baselines and the oracle"),
}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="expoctl", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    modules = {}
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ImportError:
            continue  # a subcommand whose optional dependencies are missing is simply not offered
        p = sub.add_parser(name, help=help_text, description=(module.__doc__ or help_text).strip().splitlines()[0])
        module.add_arguments(p)
        modules[name] = module
    args = parser.parse_args(argv)
    try:
        return int(modules[args.command].run(args) or 0)
    except InputError as exc:
        print(f"expoctl {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # commands that record handle Ctrl-C themselves; anything else just stops
        print(f"expoctl {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
