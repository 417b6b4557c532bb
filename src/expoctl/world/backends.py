"""The renderer backends, chosen by `world.render.backend`: numba (the CPU ray caster, `renderer.Renderer`) and egl
(the same ray caster as a GLSL shader on a headless EGL OpenGL 4.5 context, `gl_renderer.GLRenderer`).
"""

from __future__ import annotations

from expoctl.world.city import City, Conditions
from expoctl.world.gl_renderer import GLRenderer
from expoctl.world.render_config import RenderConfig
from expoctl.world.renderer import Renderer


def make_renderer(city: City, render: RenderConfig | dict, conditions: Conditions | None = None) -> Renderer:
    """Build from the `world.render` config group: a `RenderConfig`, or its mapping (keys as in
    conf/world/default.yaml; unknown keys are errors). backend 'egl' returns a gl_renderer.GLRenderer (ConfigError
    world.render.backend if no EGL context)."""
    if not isinstance(render, RenderConfig):
        render = RenderConfig.from_dict(render)
    cls = GLRenderer if render.backend == "egl" else Renderer
    return cls(city, render, conditions=conditions)
