"""Tiny synthetic raw dual-camera sequences for tests (import: `from synthetic_raw import ...`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from expoctl.raw.format import SequenceWriter

PROJECT_ROOT = Path(__file__).resolve().parents[1]
SHARED = PROJECT_ROOT.parent / "shared"


def textured_frame(rng: np.random.Generator, height: int, width: int, shift_px: int = 0) -> np.ndarray:
    """A broadband textured RGB image (smoothed noise at several scales), shifted right by `shift_px`."""
    import cv2

    base = np.zeros((height, width + 64), np.float32)
    for scale in (2, 5, 13):
        n = rng.standard_normal((height // scale + 2, (width + 64) // scale + 2)).astype(np.float32)
        base += cv2.resize(n, (width + 64, height), interpolation=cv2.INTER_CUBIC)
    base = (base - base.min()) / (np.ptp(base) + 1e-9)
    crop = base[:, 32 - shift_px : 32 - shift_px + width]
    rgb = np.stack([crop, crop * 0.9 + 0.05, crop * 0.8 + 0.1], axis=-1)
    return (rgb * 255).astype(np.uint8)


def write_synthetic_sequence(seq_dir: Path, n_frames: int = 6, height: int = 48, width: int = 64, seed: int = 0,
                             sections: list | None = None) -> Path:
    """A valid raw sequence: both cameras, monotonic timestamps, settings inside the ranges."""
    meta = {
        "source": "sim",
        "rig": {"baseline_m": 0.0392, "fps": 15.0, "resolution": [width, height],
                "intrinsics": {"fx": width * 0.8, "fy": width * 0.8, "cx": width / 2, "cy": height / 2}},
        "world": "synthetic", "route": "none", "reference_controller": "agae", "seed": seed,
        "sections": sections if sections is not None else [
            {"start_frame": 0, "end_frame": n_frames // 2 - 1, "kind": "static"},
            {"start_frame": n_frames // 2, "end_frame": n_frames - 1, "kind": "dynamic"}],
    }
    with SequenceWriter(seq_dir, meta) as w:
        for f in range(n_frames):
            for cam in (1, 2):
                w.add_frame(f, cam, f * 66_666_667, 3.0 * cam, 1000.0 + 100 * f,
                            textured_frame(np.random.default_rng(seed * 1000 + f), height, width, shift_px=cam))
    return seq_dir
