"""The one preprocessing path from camera frames to the network's 15-channel input (training and deployment).

Paper bug 3 (docs/network.md): the authors scaled the gain/exposure planes to 0–255 in training but 0–1 in
deployment, and deployed on BGR. Here both training (`expoctl.net.dataset`) and the deployed controller
(`expoctl.controllers.learned`) call exactly these two functions:

1. `prepare_frame(image_uint8_rgb, store_hw, input_hw)` — a camera frame (any size, 8-bit RGB) → uint8 RGB at the
   network input size. Step one reproduces ingest bit for bit: `cv2.resize(img, (W, H), interpolation=cv2.INTER_AREA)`
   to the image-store size (a no-op when the frame already has that size, which is the case for stored frames).
   Step two, only when the model's input size differs from the store size, resizes again with INTER_AREA.
   Training builds its frame cache with this function from stored frames; deployment from full-size camera frames,
   so a deployed frame passes through the same resize chain as a training frame did.
2. `assemble_input(frames_uint8, gain_norm, exposure_norm)` — a batch of three-frame stacks → float32 tensor
   (B, 15, h, w). Images become RGB in [0, 1] (uint8 / 255); every frame gets a constant plane of its scaled gain and
   one of its scaled exposure (`expoctl.camera.ranges`, linear or log per `model.exposure_scale`, also in [0, 1] — "scaled to the image intensity range").

Channel order (15 = 3 frames × 5): frame t → channels 0–4, frame t−1 → 5–9, frame t−2 → 10–14; within a frame
[R, G, B, gain_norm, exposure_norm].
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np
import torch

from expoctl.camera.ranges import exposure_to_norm, gain_to_norm

N_FRAMES = 3
CHANNELS_PER_FRAME = 5
N_INPUT_CHANNELS = N_FRAMES * CHANNELS_PER_FRAME
CHANNEL_NAMES = tuple(f"{c}_{f}" for f in ("t", "t-1", "t-2") for c in ("R", "G", "B", "gain", "exposure"))


def as_hw(size) -> tuple[int, int]:
    """An int (square) or a (height, width) pair → (height, width)."""
    if isinstance(size, (int, np.integer)):
        return int(size), int(size)
    h, w = size
    return int(h), int(w)


def resize_area(image_uint8: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """Resize an H×W×3 uint8 image to (h, w) with INTER_AREA, exactly as ingest does; no-op when already that size."""
    h, w = hw
    if image_uint8.shape[0] == h and image_uint8.shape[1] == w:
        return image_uint8
    return cv2.resize(image_uint8, (w, h), interpolation=cv2.INTER_AREA)


def prepare_frame(image_uint8_rgb: np.ndarray, store_hw, input_hw) -> np.ndarray:
    """Camera frame (H×W×3 uint8 RGB, any size) → uint8 RGB (h, w, 3) at the network input size (see module doc)."""
    image = np.asarray(image_uint8_rgb)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"expected an H×W×3 uint8 RGB image, got shape {image.shape} dtype {image.dtype}")
    stored = resize_area(image, as_hw(store_hw))
    return np.ascontiguousarray(resize_area(stored, as_hw(input_hw)))


def settings_to_norm(gain_db, exposure_us, exposure_scale: str = "linear") -> tuple[np.ndarray, np.ndarray]:
    """Settings → the float32 [0, 1] values the planes carry (same scaling as the model's targets:
    `model.exposure_scale`, see `expoctl.camera.ranges`)."""
    return (gain_to_norm(gain_db).astype(np.float32),
            exposure_to_norm(exposure_us, exposure_scale).astype(np.float32))


def assemble_input(frames_uint8: torch.Tensor, gain_norm: torch.Tensor, exposure_norm: torch.Tensor) -> torch.Tensor:
    """Build the network input.

    frames_uint8: (B, 3, 3, h, w) uint8 — sample, frame (t, t−1, t−2), RGB channel, row, column.
    gain_norm, exposure_norm: (B, 3) float32, per frame, in the same frame order.
    Returns (B, 15, h, w) float32, channel order as in the module doc.
    """
    if frames_uint8.dtype != torch.uint8 or frames_uint8.ndim != 5 or frames_uint8.shape[1:3] != (N_FRAMES, 3):
        raise ValueError(f"frames must be uint8 (B, 3, 3, h, w), got {tuple(frames_uint8.shape)} {frames_uint8.dtype}")
    b, _, _, h, w = frames_uint8.shape
    out = torch.empty((b, N_FRAMES, CHANNELS_PER_FRAME, h, w), dtype=torch.float32)
    torch.div(frames_uint8, 255.0, out=out[:, :, :3])  # written in place: no concatenation copy of a large batch
    out[:, :, 3] = gain_norm.to(torch.float32)[:, :, None, None]
    out[:, :, 4] = exposure_norm.to(torch.float32)[:, :, None, None]
    return out.view(b, N_INPUT_CHANNELS, h, w)


def stack_frames(frames_hwc: Sequence[np.ndarray]) -> torch.Tensor:
    """Three prepared (h, w, 3) uint8 frames in order t, t−1, t−2 → a (1, 3, 3, h, w) uint8 tensor."""
    arr = np.stack([np.asarray(f).transpose(2, 0, 1) for f in frames_hwc])[None]
    return torch.from_numpy(np.ascontiguousarray(arr))
