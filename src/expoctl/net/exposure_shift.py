"""Synthetic over-exposure: a training sample as the camera would have delivered it k EV brighter.

Why: in closed loop the network meets saturated frames (a start above the scene's level, every tunnel exit) that its
data hardly contain: camera 1 follows a well-exposed reference and camera 2 stays within about ±1 EV of it. Whether a
white frame is then an absorbing state was a draw of training: replicates on fixed data ended at +0.6…+2.1 EV or
+5.6…+6.1 EV white from the same +6 EV start (docs/runs/calibrated_seeds/README.md). This shows the network, during training,
the states it has to leave, with the label it should go to.

Physics: the delivered code is F(x) (`expoctl.camera.response`), with x the black-subtracted linear signal, which is
proportional to exposure time × gain. A camera k EV brighter delivers F(min(2^k·x, 1)): the same scene, more of it
clipped. This is exact for brightening up to noise, which is why shifts are ≥ 0: darkening cannot be undone (a
clipped pixel's true value is unknown). The settings move by the same k, on exposure time first and then on gain
(as a camera's AE spends an exposure product), and k is capped per sample so all three frames stay within the
camera's range. The label stays as it is: it is the best absolute setting for the next frame, a property of the
scene, not of the settings the network happens to look at.

Not exact: noise (shot and read noise are scaled with the signal, not re-drawn: more exposure would lower the
relative shot noise, more gain would not), the frames are shifted after the area resize to the network input (a
pixel on an edge averages codes, not linear values) and codes are dequantised and requantised.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from expoctl.camera.ranges import (EXPOSURE_US_MAX, GAIN_DB_MAX, GAIN_DB_MIN, exposure_to_norm, gain_to_norm,
                                   norm_to_exposure)
from expoctl.camera.response import Response

DB_PER_EV = 20.0 * math.log10(2.0)  # a gain of 6.02 dB doubles the signal, as one EV of exposure time does
# The whole settings range in EV: exposure 75 µs … 30 ms (8.64 EV) and gain 0 … 30 dB (4.98 EV)
MAX_SHIFT_EV = math.log2(EXPOSURE_US_MAX / 75.0) + (GAIN_DB_MAX - GAIN_DB_MIN) / DB_PER_EV


def encoding_thresholds(response: Response, iterations: int = 60) -> np.ndarray:
    """(256, 3) float64: per channel, the smallest linear signal in [0, 1] the response encodes to at least each code
    (bisection on `Response.linear_to_8bit`, so the encoding below agrees with the camera's own); inf for a code
    that no signal up to full scale reaches."""
    codes = np.arange(256, dtype=np.float64)[:, None]
    lo, hi = np.zeros((256, 3)), np.ones((256, 3))
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        at_least = response.linear_to_8bit(mid) >= codes
        hi = np.where(at_least, mid, hi)
        lo = np.where(at_least, lo, mid)
    code = codes[:, 0][:, None]
    black = response.linear_to_8bit(np.zeros((1, 3)))[0]  # above 0 with a positive pedestal
    hi[code <= black[None, :]] = 0.0  # every signal reaches these
    full_scale = response.linear_to_8bit(np.ones((1, 3)))[0]  # below 255 with a white balance < 1
    hi[code > full_scale[None, :]] = np.inf  # … and none these
    return hi


class ExposureShift:
    """Brightens samples of a batch by their own k ≥ 0 EV (module doc). One per training run (it holds the
    response's lookup tables)."""

    def __init__(self, response: Response, exposure_scale: str):
        self.exposure_scale = exposure_scale
        codes = np.repeat(np.arange(256, dtype=np.uint8)[:, None], 3, axis=1)
        self._to_linear = torch.from_numpy(response.uint8_to_linear(codes).astype(np.float64))  # (256, 3)
        self._thresholds = torch.from_numpy(encoding_thresholds(response)[1:])  # (255, 3): codes 1 … 255

    def headroom_ev(self, gain_norm: torch.Tensor, exposure_norm: torch.Tensor) -> torch.Tensor:
        """(B,) the largest shift every frame of each sample allows (exposure to its maximum, then gain)."""
        gain_db, exposure_us = self._settings(gain_norm, exposure_norm)
        room = torch.log2(EXPOSURE_US_MAX / exposure_us).clamp(min=0) + (GAIN_DB_MAX - gain_db).clamp(min=0) / DB_PER_EV
        return room.min(dim=1).values

    def apply(self, frames: torch.Tensor, gain_norm: torch.Tensor, exposure_norm: torch.Tensor,
              shift_ev: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """frames (B, 3, 3, h, w) uint8, planes (B, 3), shift_ev (B,) ≥ 0 → the brightened frames and planes. Samples
        with shift 0 come back unchanged; a shift beyond a sample's headroom is cut to it."""
        shift = torch.minimum(shift_ev.to(torch.float64), self.headroom_ev(gain_norm, exposure_norm)).clamp(min=0)
        rows = torch.nonzero(shift > 0).flatten()
        if len(rows) == 0:
            return frames, gain_norm, exposure_norm
        frames, gain_norm, exposure_norm = frames.clone(), gain_norm.clone(), exposure_norm.clone()
        k = shift[rows]
        # image: code → linear (per channel) → × 2^k → clip → code
        sub = frames[rows].long()  # (n, 3 frames, 3 channels, h, w)
        lin = torch.stack([self._to_linear[sub[:, :, c], c] for c in range(3)], dim=2)
        lin = (lin * torch.exp2(k).view(-1, 1, 1, 1, 1)).clamp(max=1.0)
        out = torch.stack([torch.bucketize(lin[:, :, c].contiguous(), self._thresholds[:, c].contiguous(), right=True)
                           for c in range(3)], dim=2)
        frames[rows] = out.to(torch.uint8)
        # settings: exposure time first, then gain
        gain_db, exposure_us = self._settings(gain_norm[rows], exposure_norm[rows])
        kk = k.view(-1, 1)
        new_exposure = torch.minimum(exposure_us * torch.exp2(kk), torch.full_like(exposure_us, EXPOSURE_US_MAX))
        new_exposure = torch.maximum(new_exposure, exposure_us)  # a frame already above the maximum keeps its time
        rest_ev = kk - torch.log2(new_exposure / exposure_us)
        new_gain = (gain_db + rest_ev * DB_PER_EV).clamp(max=GAIN_DB_MAX)
        gain_norm[rows] = torch.from_numpy(gain_to_norm(new_gain.numpy()).astype(np.float32))
        exposure_norm[rows] = torch.from_numpy(exposure_to_norm(new_exposure.numpy(), self.exposure_scale)
                                               .astype(np.float32))
        return frames, gain_norm, exposure_norm

    def _settings(self, gain_norm: torch.Tensor, exposure_norm: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Planes → (gain dB, exposure µs), float64, unclamped (a sensor exposure below 75 µs stays what it was)."""
        gain_db = GAIN_DB_MIN + gain_norm.to(torch.float64) * (GAIN_DB_MAX - GAIN_DB_MIN)
        exposure_us = torch.from_numpy(norm_to_exposure(exposure_norm.numpy().astype(np.float64), self.exposure_scale,
                                                        clamp=False))
        return gain_db, exposure_us


def draw_shifts(n: int, probability: float, range_ev: tuple[float, float], generator: torch.Generator) -> torch.Tensor:
    """(n,) float32: 0 for most samples, U[range_ev] for a `probability` share of them."""
    chosen = torch.rand(n, generator=generator) < probability
    lo, hi = range_ev
    k = lo + (hi - lo) * torch.rand(n, generator=generator)
    return torch.where(chosen, k, torch.zeros_like(k))
