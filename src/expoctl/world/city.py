"""Cities and traversals: `load_city(name_or_dict) -> City`, `City.traversal(...) -> Trajectory`.

Conventions
- World frame: x east, y north, z up, metres. Time in seconds from the trajectory start (timestamps in ns).
- Poses are 4×4 camera-to-world matrices for the rig's left camera (camera 1) in the OpenCV camera convention:
  camera x right, y down, z forward (optical axis). A world point X maps to camera coordinates inv(pose) @ X.
- The vehicle drives the centre of `road.lane_of_travel` (lanes numbered left to right) in the +s direction at a
  constant speed, camera at `traversal.camera_height_m` above the road, with small pitch/roll/yaw vibration.
"""

from __future__ import annotations

import math
import os
import uuid
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from expoctl.config_reader import Problems, Section
from expoctl.errors import ConfigError
from expoctl.world import clear_sky
from expoctl.world.cities import city_config
from expoctl.world.render_config import RenderConfig
from expoctl.world.route import Route, build_segments

SUN_DISK_SOLID_ANGLE_SR = 6.8e-5  # the sun's disk (0.533° diameter)


@dataclass
class Conditions:
    """Lighting of one traversal (absolute units)."""

    sun_direction: np.ndarray  # unit vector toward the sun, world frame
    sun_illuminance_lux: float  # normal-incidence direct sun (0 when overcast)
    sky_zenith_cd_m2: float  # zenith luminance Lz of the sky distribution `sky`
    overcast: bool
    hdri: dict | None = None  # {path, median_cd_m2, azimuth_deg} or None
    # luminance distribution of the sky (clear_sky.SKIES): 'cie_overcast' L = Lz(1 + 2cos Z)/3, or a CIE general
    # clear sky 'cie_12' / 'cie_13' (ISO 15469) around the sun
    sky: str = clear_sky.OVERCAST

    @property
    def sky_illuminance_lux(self) -> float:
        """Horizontal illuminance from the sky distribution (not the sun): its cosine-weighted integral over the
        hemisphere, E = Lz·∫ L/Lz cos Z dω — (7π/9)·Lz for the overcast sky, a quadrature for the clear ones, so the
        sky the camera sees and the sky that lights the scene agree."""
        if self.sky == clear_sky.OVERCAST:
            return 7.0 * math.pi / 9.0 * self.sky_zenith_cd_m2
        zs = math.acos(max(-1.0, min(1.0, float(self.sun_direction[2]))))
        return clear_sky.illuminance_factor(self.sky, zs) * self.sky_zenith_cd_m2

    @property
    def global_illuminance_lux(self) -> float:
        return self.sky_illuminance_lux + self.sun_illuminance_lux * max(float(self.sun_direction[2]), 0.0)


@dataclass
class Trajectory:
    """Ground-truth camera-1 poses of one traversal, with static/dynamic sections."""

    city: str
    index: int
    seed: int
    fps: float
    speed_mps: float
    s_start_m: float
    timestamps_ns: np.ndarray  # (N,) int64, frame k at k/fps seconds (exposure starts at the timestamp)
    poses: np.ndarray  # (N, 4, 4) camera-to-world (x right, y down, z forward)
    sections: list  # [{start_frame, end_frame (inclusive), kind: static|dynamic}]
    frame_section: np.ndarray  # (N,) str
    portal_times_s: list  # [(time_s, tunnel index, "entry"|"exit")]
    conditions: Conditions
    _city: "City" = field(repr=False, default=None)
    uid: str = field(default_factory=lambda: uuid.uuid4().hex)  # identifies this trajectory in render caches

    def s_at(self, time_s):
        """Arc length along the route (m, wrapped) at time t (s since the trajectory start)."""
        return self._city.route.wrap(self.s_start_m + self.speed_mps * np.asarray(time_s, dtype=np.float64))

    def pose_at(self, time_s: float) -> np.ndarray:
        """Camera-1 pose (4×4 camera-to-world) at any time t (s since the trajectory start); used for motion blur."""
        return self._city.pose_at_s(self.s_at(time_s), float(time_s), self._vib)

    @property
    def _vib(self):
        return self._city.vibration(self.index, self.seed)


def load_city(name_or_dict: str | dict, city_dir: str | Path | None = None) -> "City":
    """Load a city by name ('train', 'validation', 'test'; YAML in `city_dir` overrides the packaged default) or
    from a full config dict (optionally `base: <name>` plus overrides). Validates before building anything."""
    return City(city_config(name_or_dict, city_dir))


_CITY_CACHE: dict[str, City] = {}


def load_city_cached(spec: str | dict, city_dir: str | None) -> "City":
    """One City per spec per process: building a city's texture atlas takes seconds, sequences share it."""
    import json

    key = json.dumps([spec, city_dir], sort_keys=True)
    if key not in _CITY_CACHE:
        _CITY_CACHE[key] = load_city(spec, city_dir)
    return _CITY_CACHE[key]


@dataclass(frozen=True)
class WorldConfig:
    """The `world` config group (conf/world/default.yaml): the city of each split, where named cities are looked up
    first, and the renderer (`world.render`)."""

    cities: dict  # split → a city name or a city config mapping (checked when loaded: `city_config`)
    city_dir: str | None = None
    render: RenderConfig = RenderConfig()

    @classmethod
    def from_dict(cls, d: Any, key: str = "world", problems: Problems | None = None) -> "WorldConfig":
        r = Section(d, key, problems)
        cities = r.value("cities", {})
        if not isinstance(cities, dict) or not all(isinstance(v, (str, dict)) for v in cities.values()):
            r.problem("cities", f"must map split names to city names or city configs, got {cities!r}")
            cities = {}
        city_dir = r.value("city_dir", None)
        if city_dir is not None and not isinstance(city_dir, str):
            r.problem("city_dir", f"must be a directory path or null, got {city_dir!r}")
            city_dir = None
        render = RenderConfig.from_dict(r.value("render", None), r.path("render"), r.problems)
        r.done()
        return cls(dict(cities), city_dir, render)

    def under(self, project_root: str | os.PathLike) -> "WorldConfig":
        """The same world with a relative `city_dir` made absolute under `project_root` (workers run elsewhere)."""
        if self.city_dir is None:
            return self
        return replace(self, city_dir=str((Path(project_root) / self.city_dir).resolve()))


def load_world_city(world_cfg: dict, split: str) -> "City":
    """The city configured for `split` in the `world` config group (conf/world/default.yaml: cities, city_dir)."""
    cities = world_cfg.get("cities") if isinstance(world_cfg, dict) else None
    if not isinstance(cities, dict):
        raise ConfigError("world.cities", "must map split names to city names or city configs")
    if split not in cities:
        raise ConfigError(f"world.cities.{split}", "no city configured for this split")
    city_dir = world_cfg.get("city_dir")
    if city_dir is not None and not isinstance(city_dir, str):
        raise ConfigError("world.city_dir", f"must be a directory path or null, got {city_dir!r}")
    return load_city(cities[split], city_dir)


def validate_world_config(world_cfg: dict) -> None:
    """Validate the whole `world` group (every configured city and the render keys) before any rendering."""
    world = WorldConfig.from_dict(world_cfg)
    if not world.cities:
        raise ConfigError("world.cities", "must map split names to city names or city configs")
    for name in world.cities.values():
        city_config(name, world.city_dir)


class City:
    def __init__(self, cfg: dict):
        self.cfg = cfg
        self.name = cfg["name"]
        self.route = Route(cfg)
        self.segments = build_segments(cfg, self.route)
        road = cfg["road"]
        self.lane_offset_m = -road["lanes"] * road["lane_width_m"] / 2 + (road["lane_of_travel"] + 0.5) * road[
            "lane_width_m"]

    # ------------------------------------------------------------------ geometry
    @property
    def length_m(self) -> float:
        return self.route.length_m

    def tunnel_spans(self):
        """[(start_s, end_s)] of every tunnel (m along the route)."""
        return [(float(t["start_m"]), float(t["start_m"]) + float(t["length_m"])) for t in self.cfg["tunnels"]]

    def texture_atlas(self):
        """Texture tiles + mip pyramids (cached per texture config in expoctl.world.textures, not on the city, so
        cities and trajectories stay small to pickle)."""
        from expoctl.world.textures import build_texture_atlas
        return build_texture_atlas(self.cfg)

    def vibration(self, index: int, seed: int):
        """Per-traversal vibration spectrum: (freqs_hz (3, K), phases (3, K), amps_rad (3, K)) for pitch, roll, yaw."""
        rng = np.random.default_rng([int(self.cfg["traversal"]["seed"]), int(index), int(seed), 3])
        amp = math.radians(float(self.cfg["traversal"]["vibration_deg"]))
        freqs = rng.uniform(1.0, 12.0, (3, 4))
        phases = rng.uniform(0, 2 * math.pi, (3, 4))
        amps = amp * np.array([1.0, 0.6, 0.3])[:, None] * rng.uniform(0.3, 1.0, (3, 4)) / 2.0
        return freqs, phases, amps

    def pose_at_s(self, s, time_s, vib=None) -> np.ndarray:
        """Camera pose on the lane of travel at arc length s, plus vibration at time t."""
        x, y, z, psi, dz = self.route.centre(s)
        x, y, z, psi, dz = (float(np.asarray(a)) for a in (x, y, z, psi, dz))
        gamma = math.atan(dz)
        fwd = np.array([math.cos(psi) * math.cos(gamma), math.sin(psi) * math.cos(gamma), math.sin(gamma)])
        right = np.array([math.sin(psi), -math.cos(psi), 0.0])
        up = np.cross(right, fwd)
        pos = np.array([x, y, z]) + right * self.lane_offset_m + up * float(self.cfg["traversal"]["camera_height_m"])
        rot = np.stack([right, -up, fwd], axis=1)
        if vib is not None:
            freqs, phases, amps = vib
            ang = (amps * np.sin(2 * math.pi * freqs * time_s + phases)).sum(axis=1)
            rot = rot @ _rot_x(ang[0]) @ _rot_z(ang[1]) @ _rot_y(ang[2])
        pose = np.eye(4)
        pose[:3, :3], pose[:3, 3] = rot, pos
        return pose

    # ------------------------------------------------------------------ traversals
    def conditions(self, index: int, seed: int) -> Conditions:
        tr = self.cfg["traversal"]
        rng = np.random.default_rng([int(tr["seed"]), int(index), int(seed), 1])
        overcast = bool(rng.random() < float(tr["overcast_probability"]))
        el = math.radians(rng.uniform(*tr["sun_elevation_deg"]))
        az = math.radians(rng.uniform(*tr["sun_azimuth_deg"]))
        e_sun = 0.0 if overcast else float(rng.uniform(*tr["sun_illuminance_lux"]))
        lz = float(rng.uniform(*tr["sky_zenith_cd_m2"]))
        # azimuth clockwise from north (compass), world x east / y north
        sun = np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])
        sky = clear_sky.OVERCAST
        # a clear sky needs the sun up; 'overcast_profile' keeps the old overcast distribution under the sun
        if not overcast and sun[2] > 0.0 and tr["clear_sky"] != "overcast_profile":
            sky = tr["clear_sky"]
            lz = clear_sky.clear_sky_zenith_cd_m2(sky, sun, e_sun, float(tr["clear_sky_horizon_cd_m2_per_100klux"]))
        return Conditions(sun, e_sun, lz, overcast, tr.get("hdri"), sky)

    def traversal(self, index: int, n_frames: int | None = None, fps: float = 15.0, seed: int = 0) -> Trajectory:
        """Traversal `index` of this city's route at `fps` frames/s.

        n_frames=None: the whole closed route once, from a start point drawn per (index, seed).
        n_frames=k: a k-frame window placed so that it contains a portal crossing (portal chosen by index) at a
        random position within its middle 60 %.
        """
        if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not fps > 0:
            raise ConfigError("world.traversal.fps", f"must be a positive number, got {fps!r}")
        if n_frames is not None and (isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer))
                                     or n_frames < 1):
            raise ConfigError("world.traversal.n_frames", f"must be a positive integer or null, got {n_frames!r}")
        tr = self.cfg["traversal"]
        rng = np.random.default_rng([int(tr["seed"]), int(index), int(seed), 2])
        speed = float(rng.uniform(*tr["speed_kmh"])) / 3.6
        portals = []
        for ti, (a, b) in enumerate(self.tunnel_spans()):
            portals += [(a, ti, "entry"), (b % self.length_m, ti, "exit")]
        if n_frames is None:
            s_start = float(rng.uniform(0, self.length_m))
            n = int(math.ceil(self.length_m / speed * fps))
        else:
            n = int(n_frames)
            if portals:
                s_cross = portals[int(index) % len(portals)][0]
                frac = rng.uniform(0.2, 0.8)
                s_start = float((s_cross - frac * (n - 1) / fps * speed) % self.length_m)
            else:
                s_start = float(rng.uniform(0, self.length_m))
        times = np.arange(n) / float(fps)
        traj = Trajectory(self.name, int(index), int(seed), float(fps), speed, s_start,
                          np.round(times * 1e9).astype(np.int64), np.zeros((n, 4, 4)), [], np.empty(n, object),
                          [], self.conditions(index, seed), self)
        vib = self.vibration(index, seed)
        s_all = traj.s_at(times)
        traj.poses = np.stack([self.pose_at_s(s, t, vib) for s, t in zip(s_all, times)])
        # portal crossings (also just outside the window, whose dynamic span may reach into it)
        before, after = float(tr["dynamic_before_s"]), float(tr["dynamic_after_s"])
        lap_s = self.length_m / speed
        dynamic = np.zeros(n, bool)
        for s_p, ti, kind in portals:
            t_c = ((s_p - s_start) % self.length_m) / speed
            for k in range(-1, int(times[-1] / lap_s) + 2):
                tc = t_c + k * lap_s
                if -before - after <= tc - 0 <= times[-1] + before + after:
                    if 0 <= tc <= times[-1]:
                        traj.portal_times_s.append((float(tc), ti, kind))
                    dynamic |= (times >= tc - before) & (times <= tc + after)
        traj.portal_times_s.sort()
        # the paper's static sections are unobstructed road: frames inside a tunnel that are not near a portal are
        # their own kind ("interior"), counted in neither the static nor the dynamic statistics
        inside = np.zeros(n, bool)
        for a, b in self.tunnel_spans():
            inside |= ((s_all - a) % self.length_m) < (b - a)
        kinds = np.where(dynamic, "dynamic", np.where(inside, "interior", "static")).astype(object)
        traj.frame_section = kinds
        traj.sections = _runs(kinds)
        return traj


def _runs(kinds: np.ndarray) -> list:
    """Maximal runs of equal section kind as [{start_frame, end_frame (inclusive), kind}]."""
    out, start = [], 0
    for k in range(1, len(kinds) + 1):
        if k == len(kinds) or kinds[k] != kinds[start]:
            out.append({"start_frame": start, "end_frame": k - 1, "kind": str(kinds[start])})
            start = k
    return out


def _rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_z(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
