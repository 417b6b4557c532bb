"""The `world.render` config group (keys of conf/world/default.yaml): its keys, backends and validation, and the
pinhole intrinsics of a render size and field of view. Shared by the renderer, the city config check and the backends.
"""

from __future__ import annotations

import math

import numpy as np

from expoctl.errors import ConfigError


def intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Pinhole K (3×3, pixels) for square pixels, principal point at the image centre."""
    if not (isinstance(width, (int, np.integer)) and width > 0 and isinstance(height, (int, np.integer)) and height > 0):
        raise ConfigError("world.render.width", f"width/height must be positive integers, got {width}x{height}")
    if not 1.0 < float(hfov_deg) < 179.0:
        raise ConfigError("world.render.hfov_deg", f"must be in (1, 179) degrees, got {hfov_deg}")
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


RENDER_KEYS = ("width", "height", "hfov_deg", "glare_fraction", "mip_bias", "tmax_m", "blur", "max_subframes",
               "share_render", "backend")
# numba: the CPU ray caster (shade.render_kernel); egl: the same ray caster as a GLSL shader on a headless EGL
# OpenGL 4.5 context (gl_renderer.GLRenderer; moderngl, e.g. Mesa llvmpipe)
BACKENDS = ("numba", "egl")


def validate_render_config(render_cfg: dict) -> None:
    """Check the `world.render` group (keys of conf/world/default.yaml) without building anything."""
    if not isinstance(render_cfg, dict):
        raise ConfigError("world.render", "must be a mapping")
    for key in render_cfg:
        if key not in RENDER_KEYS:
            raise ConfigError(f"world.render.{key}", f"unknown key; known: {', '.join(RENDER_KEYS)}")
    for key in ("width", "height", "max_subframes"):
        v = render_cfg.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int) or v < 1):
            raise ConfigError(f"world.render.{key}", f"must be a positive integer, got {v!r}")
    for key in ("hfov_deg", "glare_fraction", "mip_bias", "tmax_m"):
        v = render_cfg.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
            raise ConfigError(f"world.render.{key}", f"must be a number, got {v!r}")
    if "hfov_deg" in render_cfg and not 1.0 < render_cfg["hfov_deg"] < 179.0:
        raise ConfigError("world.render.hfov_deg", f"must be in (1, 179) degrees, got {render_cfg['hfov_deg']}")
    if "glare_fraction" in render_cfg and not 0.0 <= render_cfg["glare_fraction"] <= 0.05:
        raise ConfigError("world.render.glare_fraction", f"must be in [0, 0.05], got {render_cfg['glare_fraction']}")
    if "mip_bias" in render_cfg and not render_cfg["mip_bias"] > 0:
        raise ConfigError("world.render.mip_bias", f"must be > 0, got {render_cfg['mip_bias']}")
    if "tmax_m" in render_cfg and not render_cfg["tmax_m"] > 10:
        raise ConfigError("world.render.tmax_m", f"must be > 10 m, got {render_cfg['tmax_m']}")
    if "blur" in render_cfg and render_cfg["blur"] not in ("fast", "reference"):
        raise ConfigError("world.render.blur", f"must be 'fast' or 'reference', got {render_cfg['blur']!r}")
    if "share_render" in render_cfg and not isinstance(render_cfg["share_render"], bool):
        raise ConfigError("world.render.share_render", f"must be true or false, got {render_cfg['share_render']!r}")
    if "backend" in render_cfg and render_cfg["backend"] not in BACKENDS:
        raise ConfigError("world.render.backend", f"must be one of {', '.join(BACKENDS)}, got {render_cfg['backend']!r}")
