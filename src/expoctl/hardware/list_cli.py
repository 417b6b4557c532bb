"""List the cameras the camera backend finds (their ids are what --camera / --camera1 / --camera2 take)."""

from __future__ import annotations

import argparse

from expoctl.hardware import BACKENDS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--backend", choices=BACKENDS, default="aravis", help="camera driver (default aravis)")


def run(args: argparse.Namespace) -> int:
    from expoctl.hardware.aravis import list_cameras

    found = list_cameras()
    if not found:
        print("no cameras found (GigE Vision: same subnet as this machine; USB3 Vision: permissions on the device)")
        return 1
    print(f"{'id':<32} {'serial':<16} {'model':<24} {'protocol':<10} address")
    for c in found:
        print(f"{c['id']:<32} {c['serial']:<16} {c['model']:<24} {c['protocol']:<10} {c['address'] or c['physical_id']}")
    return 0
