"""A small synthetic training set in the pipeline's formats (samples, frames, image store) with a known answer.

For tests and benchmarks of the training code only — not the simulator. Each sequence is a textured scene under
an illumination level that drifts and jumps by several EV (tunnel-like). Camera 1 follows a lagging auto-exposure,
camera 2 gets camera 1's settings perturbed; images are clip((L·ρ·t·10^(g/20)/K)^(1/2.2)). The target for time t
is the exposure-first split of the total exposure that puts the scene of frame t+1 at mid-grey — so it depends
on the images *and* the settings planes, and a constant predictor cannot match it.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from expoctl.camera.ranges import (EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, clamp_settings, exposure_to_norm,
                                   gain_to_norm)

_K = 1e4  # radiance·µs that maps to full scale at 0 dB


def _texture(rng: np.random.Generator, hw: tuple[int, int]) -> np.ndarray:
    h, w = hw
    out = np.zeros((h, w, 3), np.float32)
    for cells, amp in ((4, 1.0), (8, 0.5), (16, 0.25)):
        small = rng.random((cells, cells, 3)).astype(np.float32)
        out += amp * cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
    out -= out.min()
    return 0.05 + 0.95 * out / max(float(out.max()), 1e-6)


def _split(total: float) -> tuple[float, float]:
    """Exposure-first split of a total exposure product (µs at 0 dB) into (gain dB, exposure µs)."""
    e = float(np.clip(total, EXPOSURE_US_MIN, EXPOSURE_US_MAX))
    g = 20.0 * np.log10(max(total / e, 1.0))
    return clamp_settings(min(g, GAIN_DB_MAX), e)


def _render(radiance: np.ndarray, level: float, gain_db: float, exposure_us: float) -> np.ndarray:
    lin = radiance * level * exposure_us * 10 ** (gain_db / 20) / _K
    return (255.0 * np.clip(lin, 0, 1) ** (1 / 2.2) + 0.5).astype(np.uint8)


def make_synthetic_dataset(root: str | Path, n_sequences: int = 3, n_frames: int = 12, hw=(32, 32),
                           seed: int = 0) -> dict[str, Path]:
    """Write frames.parquet, samples.parquet and images/<sequence>.npy under `root`; return their paths.

    Splits by sequence: the last sequence is validation, the one before it test (if ≥ 3 sequences), the rest train.
    """
    root = Path(root)
    (root / "images").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    frame_rows, sample_rows = [], []
    splits = ["train"] * n_sequences
    splits[-1] = "validation"
    if n_sequences >= 3:
        splits[-2] = "test"
    for s in range(n_sequences):
        seq = f"syn{s:03d}"
        tex = _texture(rng, hw)
        # log10 illumination: drift plus occasional jumps of ±2–4 EV (tunnel entries/exits)
        log_l = np.empty(n_frames + 1)
        log_l[0] = rng.uniform(-1.5, 0.5)
        for t in range(1, n_frames + 1):
            jump = rng.choice([-1, 1]) * rng.uniform(0.6, 1.2) if rng.random() < 0.15 else 0.0
            log_l[t] = np.clip(log_l[t - 1] + rng.normal(0, 0.08) + jump, -2.2, 1.0)
        level = 10.0 ** log_l
        store = np.empty((n_frames, 2, *hw, 3), np.uint8)
        g1, e1 = _split(_K * 0.18 / level[0])
        settings = []
        for t in range(n_frames):
            tex_t = np.roll(tex, shift=t, axis=1)  # the camera moves
            u = rng.uniform(0, 0.5, size=2)
            q = t % 4
            g2 = g1 * (1 + u[0] if q in (0, 1) else 1 - u[0]) if g1 > 0 else rng.uniform(1, 5)
            e2 = e1 * (1 + u[1] if q in (0, 2) else 1 - u[1])
            g2, e2 = clamp_settings(g2, e2)
            for cam, (g, e) in enumerate(((g1, e1), (g2, e2))):
                store[t, cam] = _render(tex_t, level[t], g, e)
                frame_rows.append(dict(sequence=seq, frame_id=t, camera=cam + 1, timestamp_ns=t * 66_666_667,
                                       gain_db=g, exposure_us=e, image_path=f"raw/{seq}/cam{cam + 1}/{t:06d}.png",
                                       split=splits[s], section="unlabelled", image_index=t))
            settings.append(((g1, e1), (g2, e2)))
            # camera 1: auto-exposure lagging half-way (in log) towards mid-grey for the current frame
            gt, et = _split(_K * 0.18 / level[t])
            p = np.sqrt(e1 * 10 ** (g1 / 20) * et * 10 ** (gt / 20))
            g1, e1 = _split(p)
        np.save(root / "images" / f"{seq}.npy", store)
        for t in range(2, n_frames):
            tg, te = _split(_K * 0.18 / level[t + 1])
            for k in range(8):
                cams = [(k >> b & 1) + 1 for b in range(3)]
                sample_rows.append(dict(sample_id=len(sample_rows), sequence=seq, frame_id=t, cam_t=cams[0],
                                        cam_t1=cams[1], cam_t2=cams[2], target_gain_norm=float(gain_to_norm(tg)),
                                        target_exposure_norm=float(exposure_to_norm(te)), split=splits[s]))
    paths = {"frames": root / "frames.parquet", "samples": root / "samples.parquet", "images_dir": root / "images"}
    pd.DataFrame(frame_rows).to_parquet(paths["frames"], index=False)
    pd.DataFrame(sample_rows).to_parquet(paths["samples"], index=False)
    return paths
