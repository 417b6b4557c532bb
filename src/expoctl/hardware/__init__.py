"""Real cameras: a small interface (`base`), one module per backend (`aravis`), the live rig that lets the library's
closed loop drive them (`live`), and the `drive` / `record` sessions and commands.

Backends are imported lazily: expoctl without the optional `camera` extra still works, it just cannot open a camera.
"""

from __future__ import annotations

BACKENDS = ("aravis",)

__all__ = ["BACKENDS", "open_camera"]


def open_camera(camera_id: str, backend: str = "aravis", **options):
    """Open the camera `camera_id` with `backend` (options: width, height, pixel_format, frame_rate_hz,
    gain_db_per_raw); raises CameraError naming the camera if it cannot."""
    from expoctl.hardware.base import CameraError

    if backend == "aravis":
        from expoctl.hardware.aravis import AravisCamera

        return AravisCamera(camera_id, **options)
    raise CameraError(f"camera backend {backend!r} is unknown (available: {', '.join(BACKENDS)})")
