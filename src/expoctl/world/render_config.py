"""The `world.render` config group (keys of conf/world/default.yaml): `RenderConfig`, the one definition of its keys
and bounds, and the pinhole intrinsics of a render size and field of view. Shared by the renderer, the city config
check, the backends and the simulated rig.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from expoctl.config_reader import Problems, Section, bounds_text
from expoctl.errors import ConfigError

# A pinhole projection x = f·X/Z with f = (width/2) / tan(hfov/2) has a finite, positive focal length exactly for
# 0° < hfov < 180°: at 0° f is infinite, at 180° it is zero and the image plane sees nothing off-axis. Any tighter
# limit (the old 1°–179° and < 170° disagreed) would be a taste, not physics; the configured 59.1° (the paper's lens)
# and the tests' 70°–90° sit well inside.
HFOV_DEG_ABOVE, HFOV_DEG_BELOW = 0.0, 180.0
# numba: the CPU ray caster (shade.render_kernel); egl: the same ray caster as a GLSL shader on a headless EGL
# OpenGL 4.5 context (gl_renderer.GLRenderer; moderngl, e.g. Mesa llvmpipe)
BACKENDS = ("numba", "egl")
BLURS = ("fast", "reference")
# exact: the portals' configuration factors integrated per pixel (daylight.opening_factors_inline); light_map: read
# from a per-tunnel table of the same integral (daylight.light_map; opt-in, its registered bound: docs/simulator.md)
PORTAL_DAYLIGHT = ("exact", "light_map")


def intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Pinhole K (3×3, pixels) for square pixels, principal point at the image centre."""
    if not (isinstance(width, (int, np.integer)) and width > 0 and isinstance(height, (int, np.integer)) and height > 0):
        raise ConfigError("world.render.width", f"width/height must be positive integers, got {width}x{height}")
    if not HFOV_DEG_ABOVE < float(hfov_deg) < HFOV_DEG_BELOW:
        raise ConfigError("world.render.hfov_deg", f"must be a number "
                          f"{bounds_text(above=HFOV_DEG_ABOVE, below=HFOV_DEG_BELOW)} degrees, got {hfov_deg!r}")
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class RenderConfig:
    """`world.render`: image size and field of view (per camera) and the renderer's options. Defaults are
    conf/world/default.yaml's."""

    width: int = 640  # pixels
    height: int = 480
    hfov_deg: float = 59.1  # the paper's 6.23 mm lens on the IMX265 (7.07 mm wide): 2·atan(3.535 / 6.23)
    glare_fraction: float = 0.005  # share of image luminance the lens scatters into a wide halo
    mip_bias: float = 1.0  # texture footprint multiplier
    tmax_m: float = 400.0  # rays beyond this distance see sky or distant ground
    blur: str = "fast"
    max_subframes: int = 48  # reference blur: cap on sub-frame renders per exposure
    share_render: bool = False
    backend: str = "numba"
    portal_daylight: str = "exact"

    @classmethod
    def from_dict(cls, d: Any, key: str = "world.render", problems: Problems | None = None) -> "RenderConfig":
        r = Section(d, key, problems)
        # 16 px: the smallest image a front end finds features in; 8192: far beyond any sensor the rig models
        size = dict(min=16, max=8192, unit="pixels")
        cfg = cls(
            width=r.integer("width", cls.width, **size),
            height=r.integer("height", cls.height, **size),
            hfov_deg=r.number("hfov_deg", cls.hfov_deg, above=HFOV_DEG_ABOVE, below=HFOV_DEG_BELOW, unit="degrees"),
            glare_fraction=r.number("glare_fraction", cls.glare_fraction, min=0.0, max=0.05),
            mip_bias=r.number("mip_bias", cls.mip_bias, above=0.0),
            # 10 m: shorter than a road cell, the scene would end in front of the camera
            tmax_m=r.number("tmax_m", cls.tmax_m, above=10.0, unit="m"),
            blur=r.choice("blur", BLURS, cls.blur),
            max_subframes=r.integer("max_subframes", cls.max_subframes, min=1),
            share_render=r.boolean("share_render", cls.share_render),
            backend=r.choice("backend", BACKENDS, cls.backend),
            portal_daylight=r.choice("portal_daylight", PORTAL_DAYLIGHT, cls.portal_daylight),
        )
        r.done()
        return cfg

    @classmethod
    def from_world(cls, world: Any, problems: Problems | None = None) -> "RenderConfig":
        """From the whole `world` group (its `render` block)."""
        render = world.get("render") if isinstance(world, dict) else None
        return cls.from_dict(render, "world.render", problems)

    def with_size(self, width: int | None, height: int | None) -> "RenderConfig":
        """The same renderer at another image size (None keeps this one's)."""
        return replace(self, width=width or self.width, height=height or self.height)

    def validated(self, key: str = "world.render") -> "RenderConfig":
        """This config after the checks of a config read (a directly constructed one skips them): the same bounds,
        defined once in `from_dict` (ConfigError world.render.<key>)."""
        return type(self).from_dict(asdict(self), key)
