"""The simulated world: cities (routes, roadside, tunnels), absolute-luminance rendering and motion blur.

Public API:
- load_city(name_or_dict, city_dir=None) -> City      ('train', 'validation', 'test' or a config dict)
- City.traversal(index, n_frames=None, fps=15.0, seed=0) -> Trajectory
- Renderer(city, RenderConfig(width=…, hfov_deg=…, …), conditions).render(pose) -> (luminance_cd_m2 HxWx3, depth_m HxW)
- Renderer.render_exposure(trajectory, frame_index, exposure_us, camera_offset_m=0.0) -> luminance_cd_m2
- intrinsics(width, height, hfov_deg) -> 3x3 K
- load_world_city(world_cfg, split) -> City; validate_world_config(world_cfg); make_renderer(city, render_cfg)
- load_city_cached(spec, city_dir) -> City (one per spec per process); resolve_city_name(spec, city_dir, key) -> str
"""

from expoctl.world.city import (City, Conditions, Trajectory, WorldConfig, load_city, load_city_cached, load_world_city,
                                validate_world_config)
from expoctl.world.cities import deep_merge, resolve_city_name
from expoctl.world.render_config import RenderConfig, intrinsics
from expoctl.world.renderer import Renderer
from expoctl.world.backends import make_renderer

__all__ = ["City", "Conditions", "Trajectory", "Renderer", "deep_merge", "intrinsics", "load_city", "load_city_cached",
           "load_world_city", "make_renderer", "resolve_city_name", "RenderConfig", "validate_world_config", "WorldConfig"]
