"""Check raw dual-camera sequences: every problem on its own line (file, row, column); exit 1 if any."""

from __future__ import annotations

import argparse
import sys

from expoctl.errors import InputError
from expoctl.raw.format import find_sequences
from expoctl.raw.validate import check_sequence, summary_line


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("raw_dir", help="a sequence directory or a directory holding sequences (any depth)")
    parser.add_argument("--no-decode", action="store_true",
                        help="check PNG headers and end chunks only (faster; finds truncated files, misses data "
                             "corrupt inside a file)")


def run(args: argparse.Namespace) -> int:
    try:
        seqs = find_sequences(args.raw_dir)
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 1
    if not seqs:
        print(f"{args.raw_dir}: no sequences found (a sequence is a directory with sequence.yaml and frames.csv)",
              file=sys.stderr)
        return 1
    n_bad = 0
    for s in seqs:
        check = check_sequence(s, decode_images=not args.no_decode)
        if check.ok:
            print(summary_line(check))
        else:
            n_bad += 1
            for p in check.problems:
                print(p, file=sys.stderr)
    if n_bad:
        print(f"{n_bad} of {len(seqs)} sequence(s) have problems", file=sys.stderr)
        return 1
    return 0
