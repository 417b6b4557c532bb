"""Optional HDRI sky: a user's equirectangular Radiance .hdr at infinity, rescaled to an absolute level.

The map is read with OpenCV (float32 linear RGB; imageio's Pillow backend would silently return 8-bit data), and scaled
so the median luminance of its upper hemisphere equals `median_cd_m2`. The sky's horizontal illuminance used to light
outdoor surfaces is integrated from the scaled map (cosine-weighted upper hemisphere), with pixels above 50× the
median (the sun, if the map holds it) clipped so the configured direct sun is not counted twice.
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import cv2
import numpy as np

from expoctl.errors import ConfigError

_Y = np.array([0.2126, 0.7152, 0.0722], np.float32)


@functools.lru_cache(maxsize=4)
def load_hdri(path: str) -> np.ndarray:
    """Equirectangular HDR as float32 linear RGB (H, W, 3); rows run from zenith (top) to nadir."""
    if not Path(path).is_file():
        raise ConfigError("world.city.traversal.hdri.path", f"HDRI file not found: {path}")
    img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR)
    if img is None or img.dtype != np.float32 or img.ndim != 3:
        raise ConfigError("world.city.traversal.hdri.path", f"{path} is not a readable float RGB .hdr image")
    if img.shape[1] != 2 * img.shape[0]:
        raise ConfigError("world.city.traversal.hdri.path",
                          f"{path} is {img.shape[1]}x{img.shape[0]}, not a 2:1 equirectangular map")
    return np.ascontiguousarray(img[..., ::-1])


def hdri_for(spec: dict) -> tuple[np.ndarray, float, float]:
    """(map, scale to cd/m², horizontal sky illuminance in lux) for an hdri spec {path, median_cd_m2, azimuth_deg}."""
    img = load_hdri(str(spec["path"]))
    median_target = float(spec.get("median_cd_m2", 6000.0))
    if not median_target > 0:
        raise ConfigError("world.city.traversal.hdri.median_cd_m2", f"must be > 0, got {median_target}")
    h = img.shape[0]
    lum = img[: h // 2] @ _Y
    med = float(np.median(lum))
    if not med > 0:
        raise ConfigError("world.city.traversal.hdri.path", f"{spec['path']}: upper hemisphere is black")
    scale = median_target / med
    # E = Σ L cosθ dω over the upper hemisphere; row elevation el, dω = cos(el)·dθ·dφ
    el = (0.5 - (np.arange(h // 2) + 0.5) / h) * math.pi
    d_omega = np.cos(el) * (math.pi / h) * (2 * math.pi / img.shape[1])
    clipped = np.minimum(lum * scale, 50.0 * median_target)
    e_sky = float((clipped * (np.sin(el) * d_omega)[:, None]).sum())
    return img, scale, e_sky
