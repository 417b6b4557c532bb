"""Count features and inlier matches of one image pair: `expoctl match --frontend orb|viso PREV CUR`.

Prints one JSON line {"n_features_prev", "n_features_cur", "n_matches", "n_inliers"} — the same numbers the features
stage computes for a pair (same front-end parameters, same grey conversion). Problems (unreadable image, sizes that
differ, a bad --config) print one line on stderr and exit 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import yaml

from expoctl.errors import InputError
from expoctl.features.pipeline import match_images, read_grey
from expoctl.features.registry import frontend_names, make_frontend


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("prev", help="earlier image (8-bit grey or RGB, any format OpenCV reads)")
    parser.add_argument("cur", help="later image, same size")
    parser.add_argument("--frontend", choices=frontend_names(), default="orb", help="feature front end (default: orb)")
    parser.add_argument("--seed", type=int, default=0, help="RANSAC seed (default: 0)")
    parser.add_argument("--config", type=Path, default=None,
                        help="YAML with front-end parameters: conf/features/default.yaml, or a resolved config "
                             "(configs/resolved.yaml, its 'features' key); default: the built-in defaults")


def _frontend_params(config: Path | None, frontend: str) -> dict:
    if config is None:
        return {}
    try:
        data = yaml.safe_load(config.read_text())
    except OSError as exc:
        raise InputError(f"{config}: cannot read ({exc.strerror or exc})") from None
    except yaml.YAMLError as exc:
        raise InputError(f"{config}: not valid YAML ({exc})") from None
    if isinstance(data, dict) and isinstance(data.get("features"), dict):
        data = data["features"]
    if not isinstance(data, dict):
        raise InputError(f"{config}: expected a mapping with a '{frontend}' key")
    params = data.get(frontend) or {}
    if not isinstance(params, dict):
        raise InputError(f"{config}: key '{frontend}' must be a mapping, got {params!r}")
    return params


def run(args: argparse.Namespace) -> int:
    try:
        frontend = make_frontend(args.frontend, _frontend_params(args.config, args.frontend))
        prev, cur = read_grey(args.prev), read_grey(args.cur)
        if prev.shape != cur.shape:
            raise InputError(f"{args.cur}: image is {cur.shape[1]}×{cur.shape[0]} but {args.prev} is "
                             f"{prev.shape[1]}×{prev.shape[0]}; a pair needs equal sizes")
        counts = match_images(frontend, prev, cur, seed=args.seed)
    except InputError as exc:
        print(f"expoctl match: error: {exc}", file=sys.stderr)
        return 2
    except ImportError as exc:  # a front end whose module is not installed
        print(f"expoctl match: error: front end '{args.frontend}' is not available ({exc})", file=sys.stderr)
        return 2
    print(json.dumps(dataclasses.asdict(counts)))
    return 0
