"""Shared fixtures for the evaluate / oracle tests: a linear test sensor and a textured, moving, step-lit scene."""

from __future__ import annotations

import cv2
import numpy as np

from expoctl.rig.closed_loop import FunctionScene

K_DN = 25.6  # DN per (cd/m² · s · linear gain): 1000 cd/m² at 5 ms, 0 dB → 128 DN


class LinearSensor:
    """A linear 8-bit sensor: DN = clip(L · t · K_DN · 10^(g/20) + N(0, noise_dn²)); RGB = three equal channels.
    Deterministic given the generator (the interface the closed loop uses)."""

    def __init__(self, noise_dn: float = 1.0):
        self.noise_dn = noise_dn

    def capture(self, luminance_cd_m2, exposure_us, gain_db, rng):
        signal = luminance_cd_m2[..., 0] * (exposure_us * 1e-6) * K_DN * 10.0 ** (gain_db / 20.0)
        if self.noise_dn:
            signal = signal + rng.normal(0.0, self.noise_dn, signal.shape)
        grey = np.clip(np.rint(signal), 0, 255).astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)


def texture(h: int = 240, w: int = 400, seed: int = 0) -> np.ndarray:
    """Smooth random texture in [0.2, 1.8] (mean ~1): corners for ORB and the libviso2-style filters."""
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.5)
    t = (t - t.min()) / (t.max() - t.min())
    return 0.2 + 1.6 * t


def moving_scene(level_cd_m2, width: int = 160, height: int = 120, step_px: int = 2, fps: float = 15.0):
    """FunctionScene: a `width`×`height` crop of a texture sliding `step_px` per frame, scaled by level_cd_m2(frame)."""
    tex = texture(height + 20, width + 400)

    def lum(frame, exposure_us, camera):
        x0 = (frame * step_px) % 400
        crop = tex[10:10 + height, x0:x0 + width] * float(level_cd_m2(frame))
        return np.repeat(crop[..., None], 3, axis=2).astype(np.float32)

    return FunctionScene(lum, fps)
