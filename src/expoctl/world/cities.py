"""City configurations: packaged defaults, loading from YAML, merging and validation.

A city config is a plain nested dict (schema documented in conf/world/cities/train.yaml). Three names ship:
`train` (closed rectangular route with two ~80 m box tunnels), `validation` (the same city — geometry, textures and
lamps — driven under other traversal conditions: sun, sky, speed, seeds) and `test` (another city: a long curved arch
tunnel plus a short underpass, other textures/photo crops, lamps, cross-section, and disjoint seeds), and `stress`
(the test city under low sun or dark overcast).

Every value is validated before any geometry or texture is built; a bad value raises
`ConfigError("world.city.<dotted key>", ...)` naming the key.
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import yaml

from expoctl.errors import ConfigError

_TRAIN: dict[str, Any] = {
    "name": "train",
    "seed": 1101,  # geometry (roadside blocks) and texture seed
    "route": {
        # closed loop: pieces are driven in order; arcs turn left for positive angles
        "pieces": [
            {"straight_m": 320.0}, {"arc_radius_m": 45.0, "arc_angle_deg": 90.0},
            {"straight_m": 180.0}, {"arc_radius_m": 45.0, "arc_angle_deg": 90.0},
            {"straight_m": 320.0}, {"arc_radius_m": 45.0, "arc_angle_deg": 90.0},
            {"straight_m": 180.0}, {"arc_radius_m": 45.0, "arc_angle_deg": 90.0},
        ],
        "grade_amplitude_m": 1.5,  # height profile z(s) = a·sin(2π·cycles·s/L): closes by construction
        "grade_cycles": 2,
        "arc_chord_m": 4.0,  # arcs are rendered as chords of at most this length
    },
    "road": {"lanes": 2, "lane_width_m": 3.5, "shoulder_m": 0.5, "sidewalk_m": 2.5, "lane_of_travel": 1},
    "roadside": {
        "block_length_m": [12.0, 40.0],
        "offset_m": [7.5, 16.0],  # from the centreline; must exceed road + sidewalk
        "height_m": [4.0, 22.0],
        "kinds": {"facade_a": 0.3, "facade_b": 0.25, "wall": 0.15, "hedge": 0.15, "none": 0.15},
        "approach_m": 35.0,  # retaining walls (a cutting) this far outside each portal
        "props_per_100m": 6.0,  # poles (most with a sign panel) per side per 100 m of open road
    },
    "tunnels": [
        {"start_m": 90.0, "length_m": 80.0, "profile": "box", "width_m": 10.0, "height_m": 5.5, "hill_height_m": 16.0},
        {"start_m": 655.0, "length_m": 85.0, "profile": "box", "width_m": 10.0, "height_m": 5.8, "hill_height_m": 20.0},
    ],
    "lamps": {
        "spacing_m": 8.0, "luminance_cd_m2": 1.0e4, "length_m": 1.2, "width_m": 0.25,
        "colour_rgb": [1.0, 0.86, 0.62], "rows_v_m": [0.0],  # lateral positions of lamp rows on the ceiling
    },
    "lighting": {
        # daylight inside: portal_view_factor = each opening's configuration factor × the luminance seen through it
        # (expoctl.world.daylight) | exponential_tail = the two keys below (runs before issue 23)
        "daylight_model": "portal_view_factor",
        "daylight_tail_m": 18.0,  # exponential_tail: e-folding length of daylight entering each portal
        "daylight_tail_fraction": 0.2,  # exponential_tail: fraction of outside global illuminance at the portal
        # CIE 88 L20 for the threshold zone: cone_20deg = mean luminance in the 20° cone from the stopping distance
        # (expoctl.world.portal_views) | road_only = the sunlit road's luminance (runs before issue 23)
        "l20_method": "cone_20deg",
        "l20_stopping_distance_m": 60.0,  # CIE 88 stopping distance at a 60 km/h design speed, level road
        "threshold_k": 0.04,  # CIE 88 threshold zone: road luminance k·L_access (reinforced lamps)
        "threshold_length_m": 15.0,
        "transition_length_m": 20.0,
        "interreflection": 0.1,  # ambient fraction of mean lamp illuminance (tunnel surfaces)
    },
    "albedo": {  # mean diffuse reflectance per material (textures modulate around it)
        "road": 0.115, "sidewalk": 0.25, "verge": 0.12, "facade_a": 0.3, "facade_b": 0.4, "wall": 0.3,
        "hedge": 0.08, "tunnel_wall": 0.35, "tunnel_ceiling": 0.07, "portal": 0.3, "hill": 0.12, "roof": 0.15,
        "pole": 0.3, "sign": 0.5,
    },
    "textures": {"seed": 51, "photo_crop": "a", "tile_px": 1024, "texel_m": 0.01},
    "traversal": {
        "seed": 7001,
        "speed_kmh": [40.0, 70.0],
        "sun_elevation_deg": [25.0, 55.0],
        "sun_azimuth_deg": [0.0, 360.0],
        "sun_illuminance_lux": [75000.0, 92000.0],  # normal-incidence direct sun
        "overcast_probability": 0.2,  # then no direct sun
        "sky_zenith_cd_m2": [9000.0, 12000.0],  # overcast traversals: CIE overcast L(θ) = Lz(1 + 2cosθ)/3
        # clear traversals: CIE general sky type 12 (clear, low turbidity) | cie_13 (polluted) | overcast_profile
        # (the overcast distribution at sky_zenith_cd_m2 under the sun: runs before issue 23)
        "clear_sky": "cie_12",
        # level of a clear sky: mean near-horizon (0–10°) luminance per 100 klux of global horizontal illuminance;
        # middle of the measured 8 (away from the sun) … 16 (toward it) kcd/m² (van Bommel 2015, Table 20.1; CIE 88)
        "clear_sky_horizon_cd_m2_per_100klux": 12000.0,
        "vibration_deg": 0.25,
        "camera_height_m": 1.45,
        "dynamic_before_s": 2.5,  # a frame is dynamic within this window around a portal crossing
        "dynamic_after_s": 2.0,
        "hdri": None,  # optional {path, median_cd_m2, azimuth_deg}
    },
}

_VALIDATION_OVERRIDE: dict[str, Any] = {
    "name": "validation",
    "traversal": {
        "seed": 8002,
        "speed_kmh": [50.0, 80.0],
        "sun_elevation_deg": [10.0, 35.0],  # lower sun: long shadows, sun into some portals
        "sun_illuminance_lux": [60000.0, 85000.0],
        "overcast_probability": 0.3,
        "sky_zenith_cd_m2": [8000.0, 11000.0],
    },
}

_TEST: dict[str, Any] = {
    "name": "test",
    "seed": 2203,
    "route": {
        "pieces": [
            {"straight_m": 150.0}, {"arc_radius_m": 70.0, "arc_angle_deg": 180.0},
            {"straight_m": 150.0}, {"arc_radius_m": 70.0, "arc_angle_deg": 180.0},
        ],
        "grade_amplitude_m": 2.5,
        "grade_cycles": 1,
        "arc_chord_m": 4.0,
    },
    "road": {"lanes": 2, "lane_width_m": 3.5, "shoulder_m": 1.0, "sidewalk_m": 2.0, "lane_of_travel": 1},
    "roadside": {
        "block_length_m": [20.0, 60.0],
        "offset_m": [8.0, 30.0],
        "height_m": [3.0, 30.0],
        "kinds": {"facade_a": 0.2, "facade_b": 0.35, "wall": 0.2, "hedge": 0.1, "none": 0.15},
        "approach_m": 25.0,
        "props_per_100m": 4.0,
    },
    "tunnels": [
        # a long curved tunnel on the second half of the first bend (exit-ramp-like), arch cross-section
        {"start_m": 230.0, "length_m": 190.0, "profile": "arch", "width_m": 11.0, "height_m": 6.8,
         "hill_height_m": 24.0},
        # a short underpass on the second bend
        {"start_m": 610.0, "length_m": 30.0, "profile": "box", "width_m": 11.0, "height_m": 5.0,
         "hill_height_m": 9.0},
    ],
    "lamps": {
        "spacing_m": 12.0, "luminance_cd_m2": 1.4e4, "length_m": 1.5, "width_m": 0.3,
        "colour_rgb": [0.92, 0.97, 1.08], "rows_v_m": [-2.5, 2.5],
    },
    "lighting": {
        "daylight_model": "portal_view_factor", "daylight_tail_m": 25.0, "daylight_tail_fraction": 0.25,
        "l20_method": "cone_20deg", "l20_stopping_distance_m": 60.0, "threshold_k": 0.03, "threshold_length_m": 30.0,
        "transition_length_m": 40.0, "interreflection": 0.12,
    },
    "albedo": {
        "road": 0.1, "sidewalk": 0.22, "verge": 0.1, "facade_a": 0.35, "facade_b": 0.28, "wall": 0.25,
        "hedge": 0.07, "tunnel_wall": 0.45, "tunnel_ceiling": 0.06, "portal": 0.25, "hill": 0.1, "roof": 0.12,
        "pole": 0.25, "sign": 0.45,
    },
    "textures": {"seed": 977, "photo_crop": "b", "tile_px": 1024, "texel_m": 0.012},
    "traversal": {
        "seed": 9403,
        "speed_kmh": [35.0, 90.0],
        "sun_elevation_deg": [8.0, 55.0],
        "sun_azimuth_deg": [0.0, 360.0],
        "sun_illuminance_lux": [60000.0, 95000.0],
        "overcast_probability": 0.25,
        "sky_zenith_cd_m2": [8000.0, 13000.0],
        "clear_sky": "cie_12",
        "clear_sky_horizon_cd_m2_per_100klux": 12000.0,
        "vibration_deg": 0.35,
        "camera_height_m": 1.5,
        "dynamic_before_s": 2.5,
        "dynamic_after_s": 2.0,
        "hdri": None,
    },
}

_STRESS_OVERRIDE: dict[str, Any] = {
    # the test city under hard light: low sun (often in view at exits or shining into entries) or dark overcast
    "name": "stress",
    "traversal": {
        "seed": 9977,
        "sun_elevation_deg": [3.0, 12.0],
        "sun_illuminance_lux": [30000.0, 70000.0],
        "overcast_probability": 0.4,
        "sky_zenith_cd_m2": [1500.0, 5000.0],
    },
}

CITY_NAMES = ("train", "validation", "test", "stress")
MATERIALS = ("road", "sidewalk", "verge", "facade_a", "facade_b", "wall", "hedge", "tunnel_wall", "tunnel_ceiling",
             "portal", "hill", "roof", "pole", "sign")
ROADSIDE_KINDS = ("facade_a", "facade_b", "wall", "hedge", "none")
CLEAR_SKIES = ("cie_12", "cie_13", "overcast_profile")  # traversal.clear_sky (expoctl.world.clear_sky)
DAYLIGHT_MODELS = ("portal_view_factor", "exponential_tail")  # lighting.daylight_model
L20_METHODS = ("cone_20deg", "road_only")  # lighting.l20_method


def deep_merge(base: dict, override: dict) -> dict:
    """Return base updated recursively by override (dicts merge, everything else replaces)."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def packaged_city(name: str) -> dict:
    """The packaged default config of a named city (a fresh copy)."""
    if name == "train":
        return copy.deepcopy(_TRAIN)
    if name == "validation":
        return deep_merge(_TRAIN, _VALIDATION_OVERRIDE)
    if name == "test":
        return copy.deepcopy(_TEST)
    if name == "stress":
        return deep_merge(_TEST, _STRESS_OVERRIDE)
    raise ConfigError("world.city", f"unknown city {name!r}; known cities: {', '.join(CITY_NAMES)} (or pass a dict)")


def city_config(name_or_dict: str | dict, city_dir: str | Path | None = None) -> dict:
    """Resolve a city name (YAML in `city_dir` first, then packaged defaults) or a dict into a validated config.

    A dict may carry `base: <name>` to start from a named city and override only some keys.
    """
    if isinstance(name_or_dict, dict):
        cfg = copy.deepcopy(name_or_dict)
        base = cfg.pop("base", None)
        if base is not None:
            cfg = deep_merge(city_config(base, city_dir), cfg)
    elif isinstance(name_or_dict, str):
        path = Path(city_dir) / f"{name_or_dict}.yaml" if city_dir is not None else None
        if path is not None and path.is_file():
            with open(path) as fh:
                loaded = yaml.safe_load(fh)
            if not isinstance(loaded, dict):
                raise ConfigError("world.city", f"{path} does not hold a mapping")
            return city_config(loaded, city_dir)
        if name_or_dict not in CITY_NAMES:
            raise ConfigError("world.city", f"unknown city {name_or_dict!r}; known cities: "
                              f"{', '.join(known_city_names(city_dir))} (or pass a dict)")
        cfg = packaged_city(name_or_dict)
    else:
        raise ConfigError("world.city", f"expected a city name or a dict, got {type(name_or_dict).__name__}")
    validate_city(cfg)
    return cfg


def known_city_names(city_dir: str | Path | None) -> list[str]:
    """Every city name `city_config` accepts with `city_dir`: the packaged ones, then the YAML files in `city_dir`
    (the scenario cities conf/world/cities/underpass.yaml, ramp_tunnel.yaml, …)."""
    files = sorted(p.stem for p in Path(city_dir).glob("*.yaml")) if city_dir is not None else []
    return list(CITY_NAMES) + [n for n in files if n not in CITY_NAMES]


def resolve_city_name(spec: Any, city_dir: str | None, key: str) -> str:
    """The name of a city (validates it: an unknown name or bad key raises ConfigError under `key`)."""
    if not (isinstance(spec, str) and spec) and not isinstance(spec, dict):
        raise ConfigError(key, f"must be a city name or a city config mapping, got {spec!r}")
    try:
        return str(city_config(spec, city_dir)["name"])
    except ConfigError as exc:
        sub = exc.key[len("world.city"):] if exc.key.startswith("world.city") else ""
        raise ConfigError(key + sub, exc.problem) from None


# ---------------------------------------------------------------- validation helpers
def _get(cfg: dict, dotted: str):
    node: Any = cfg
    for part in dotted.split("."):
        if isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
            continue
        if not isinstance(node, dict) or part not in node:
            raise ConfigError(f"world.city.{dotted}", "missing")
        node = node[part]
    return node


def _num(cfg, dotted, lo=None, hi=None, lo_open=False):
    value = _get(cfg, dotted)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"world.city.{dotted}", f"must be a finite number, got {value!r}")
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise ConfigError(f"world.city.{dotted}", f"must be {'>' if lo_open else '>='} {lo}, got {value}")
    if hi is not None and value > hi:
        raise ConfigError(f"world.city.{dotted}", f"must be <= {hi}, got {value}")
    return float(value)


def _range(cfg, dotted, lo=None, hi=None, lo_open=False):
    value = _get(cfg, dotted)
    key = f"world.city.{dotted}"
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ConfigError(key, f"must be a [min, max] pair, got {value!r}")
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ConfigError(key, f"must hold finite numbers, got {value!r}")
        if lo is not None and (v <= lo if lo_open else v < lo):
            raise ConfigError(key, f"values must be {'>' if lo_open else '>='} {lo}, got {value!r}")
        if hi is not None and v > hi:
            raise ConfigError(key, f"values must be <= {hi}, got {value!r}")
    if value[0] > value[1]:
        raise ConfigError(key, f"inverted range: min {value[0]} > max {value[1]}")
    return float(value[0]), float(value[1])


def route_length_m(cfg: dict) -> float:
    total = 0.0
    for p in cfg["route"]["pieces"]:
        total += p["straight_m"] if "straight_m" in p else p["arc_radius_m"] * math.radians(abs(p["arc_angle_deg"]))
    return total


def validate_city(cfg: dict) -> None:
    """Check every key the world uses; raise ConfigError naming the first bad key."""
    if not isinstance(cfg.get("name"), str):
        raise ConfigError("world.city.name", "missing or not a string")
    _num(cfg, "seed", lo=0)
    pieces = _get(cfg, "route.pieces")
    if not isinstance(pieces, list) or not pieces:
        raise ConfigError("world.city.route.pieces", "must be a non-empty list")
    heading = 0.0
    x = y = 0.0
    min_radius = math.inf
    for i, p in enumerate(pieces):
        key = f"route.pieces.{i}"
        if not isinstance(p, dict):
            raise ConfigError(f"world.city.{key}", "must be a mapping")
        if "straight_m" in p:
            length = p["straight_m"]
            if isinstance(length, bool) or not isinstance(length, (int, float)) or not length > 0:
                raise ConfigError(f"world.city.{key}.straight_m", f"must be a positive length, got {length!r}")
            x += length * math.cos(heading)
            y += length * math.sin(heading)
        elif "arc_radius_m" in p and "arc_angle_deg" in p:
            r, a = p["arc_radius_m"], p["arc_angle_deg"]
            if isinstance(r, bool) or not isinstance(r, (int, float)) or not r > 0:
                raise ConfigError(f"world.city.{key}.arc_radius_m", f"must be a positive radius, got {r!r}")
            if isinstance(a, bool) or not isinstance(a, (int, float)) or a == 0 or abs(a) > 360:
                raise ConfigError(f"world.city.{key}.arc_angle_deg", f"must be non-zero, |angle| <= 360, got {a!r}")
            k = math.copysign(1.0 / r, a)
            h1 = heading + math.radians(a)
            x += (math.sin(h1) - math.sin(heading)) / k
            y -= (math.cos(h1) - math.cos(heading)) / k
            heading = h1
            min_radius = min(min_radius, r)
        else:
            raise ConfigError(f"world.city.{key}", "needs straight_m, or arc_radius_m and arc_angle_deg")
    turns = math.degrees(heading) / 360.0
    if abs(turns - round(turns)) > 1e-6 or round(turns) == 0 or math.hypot(x, y) > 0.5:
        raise ConfigError("world.city.route.pieces",
                          f"route does not close: ends {math.hypot(x, y):.2f} m from its start, "
                          f"heading turned {math.degrees(heading):.1f} deg (need a closed loop)")
    length = route_length_m(cfg)
    _num(cfg, "route.grade_amplitude_m", lo=0.0, hi=20.0)
    cycles = _get(cfg, "route.grade_cycles")
    if isinstance(cycles, bool) or not isinstance(cycles, int) or cycles < 0:
        raise ConfigError("world.city.route.grade_cycles", f"must be an integer >= 0, got {cycles!r}")
    _num(cfg, "route.arc_chord_m", lo=0.5, hi=20.0)

    lanes = _get(cfg, "road.lanes")
    if isinstance(lanes, bool) or not isinstance(lanes, int) or not 1 <= lanes <= 6:
        raise ConfigError("world.city.road.lanes", f"must be an integer in 1..6, got {lanes!r}")
    lane_w = _num(cfg, "road.lane_width_m", lo=2.0, hi=5.0)
    shoulder = _num(cfg, "road.shoulder_m", lo=0.0, hi=5.0)
    sidewalk = _num(cfg, "road.sidewalk_m", lo=0.0, hi=10.0)
    lot = _get(cfg, "road.lane_of_travel")
    if isinstance(lot, bool) or not isinstance(lot, int) or not 0 <= lot < lanes:
        raise ConfigError("world.city.road.lane_of_travel", f"must be a lane index in 0..{lanes - 1}, got {lot!r}")
    road_half = lanes * lane_w / 2 + shoulder

    _range(cfg, "roadside.block_length_m", lo=1.0, lo_open=False)
    off = _range(cfg, "roadside.offset_m", lo=0.0)
    if off[0] < road_half + sidewalk:
        raise ConfigError("world.city.roadside.offset_m",
                          f"min offset {off[0]} m is inside the road + sidewalk ({road_half + sidewalk:.2f} m)")
    if off[1] > 0.7 * min_radius:
        raise ConfigError("world.city.roadside.offset_m",
                          f"max offset {off[1]} m exceeds 0.7 x the tightest arc radius ({min_radius} m)")
    _range(cfg, "roadside.height_m", lo=0.0, lo_open=True)
    kinds = _get(cfg, "roadside.kinds")
    if not isinstance(kinds, dict) or not kinds:
        raise ConfigError("world.city.roadside.kinds", "must map kinds to probabilities")
    for k, p in kinds.items():
        if k not in ROADSIDE_KINDS:
            raise ConfigError(f"world.city.roadside.kinds.{k}", f"unknown kind; known: {', '.join(ROADSIDE_KINDS)}")
        _num(cfg, f"roadside.kinds.{k}", lo=0.0)
    if sum(kinds.values()) <= 0:
        raise ConfigError("world.city.roadside.kinds", "probabilities sum to zero")
    _num(cfg, "roadside.approach_m", lo=0.0)
    _num(cfg, "roadside.props_per_100m", lo=0.0, hi=100.0)

    tunnels = _get(cfg, "tunnels")
    if not isinstance(tunnels, list):
        raise ConfigError("world.city.tunnels", "must be a list")
    spans = []
    for i, t in enumerate(tunnels):
        key = f"tunnels.{i}"
        if not isinstance(t, dict):
            raise ConfigError(f"world.city.{key}", "must be a mapping")
        start = _num(cfg, f"{key}.start_m", lo=0.0)
        tl = _num(cfg, f"{key}.length_m", lo=0.0, lo_open=True)
        if start + tl > length:
            raise ConfigError(f"world.city.{key}.length_m", f"tunnel ends at {start + tl} m, past the route end ({length:.1f} m)")
        if t.get("profile") not in ("box", "arch"):
            raise ConfigError(f"world.city.{key}.profile", f"must be 'box' or 'arch', got {t.get('profile')!r}")
        w = _num(cfg, f"{key}.width_m", lo=0.0, lo_open=True)
        if w / 2 < road_half:
            raise ConfigError(f"world.city.{key}.width_m", f"{w} m is narrower than the road ({2 * road_half:.2f} m)")
        h = _num(cfg, f"{key}.height_m", lo=3.0, hi=15.0)
        hill = _num(cfg, f"{key}.hill_height_m", lo=0.0)
        if hill <= h:
            raise ConfigError(f"world.city.{key}.hill_height_m", f"must exceed the tunnel height {h} m, got {hill}")
        spans.append((start, start + tl, i))
    spans.sort()
    for (a0, a1, i), (b0, b1, j) in zip(spans, spans[1:]):
        if b0 < a1 + 1.0:
            raise ConfigError(f"world.city.tunnels.{j}.start_m", f"overlaps tunnel {i} (ends at {a1} m)")

    _num(cfg, "lamps.spacing_m", lo=0.5, hi=100.0)
    _num(cfg, "lamps.luminance_cd_m2", lo=0.0)
    _num(cfg, "lamps.length_m", lo=0.0, lo_open=True)
    _num(cfg, "lamps.width_m", lo=0.0, lo_open=True)
    colour = _get(cfg, "lamps.colour_rgb")
    if not isinstance(colour, (list, tuple)) or len(colour) != 3 or any(
            isinstance(c, bool) or not isinstance(c, (int, float)) or c <= 0 for c in colour):
        raise ConfigError("world.city.lamps.colour_rgb", f"must be three positive numbers, got {colour!r}")
    rows = _get(cfg, "lamps.rows_v_m")
    if not isinstance(rows, (list, tuple)) or not rows or any(
            isinstance(r, bool) or not isinstance(r, (int, float)) for r in rows):
        raise ConfigError("world.city.lamps.rows_v_m", f"must be a non-empty list of lateral positions, got {rows!r}")

    for key, allowed in (("daylight_model", DAYLIGHT_MODELS), ("l20_method", L20_METHODS)):
        if _get(cfg, f"lighting.{key}") not in allowed:
            raise ConfigError(f"world.city.lighting.{key}",
                              f"must be one of {', '.join(allowed)}, got {_get(cfg, f'lighting.{key}')!r}")
    # CIE 88 stopping distances run from ~15 m (20 km/h) to ~250 m (120 km/h, downhill)
    _num(cfg, "lighting.l20_stopping_distance_m", lo=5.0, hi=400.0)
    _num(cfg, "lighting.daylight_tail_m", lo=0.0, lo_open=True, hi=200.0)
    _num(cfg, "lighting.daylight_tail_fraction", lo=0.0, hi=1.0)
    _num(cfg, "lighting.threshold_k", lo=0.0, hi=0.2)
    _num(cfg, "lighting.threshold_length_m", lo=0.0)
    _num(cfg, "lighting.transition_length_m", lo=0.0)
    _num(cfg, "lighting.interreflection", lo=0.0, hi=1.0)
    for m in MATERIALS:
        _num(cfg, f"albedo.{m}", lo=0.0, lo_open=True, hi=1.0)
    _num(cfg, "textures.seed", lo=0)
    if _get(cfg, "textures.photo_crop") not in ("a", "b"):
        raise ConfigError("world.city.textures.photo_crop", "must be 'a' or 'b' (disjoint halves of each photo)")
    tile = _get(cfg, "textures.tile_px")
    if tile not in (256, 512, 1024, 2048):
        raise ConfigError("world.city.textures.tile_px", f"must be 256, 512, 1024 or 2048, got {tile!r}")
    _num(cfg, "textures.texel_m", lo=0.001, hi=0.1)

    _num(cfg, "traversal.seed", lo=0)
    _range(cfg, "traversal.speed_kmh", lo=0.0, lo_open=True, hi=250.0)
    _range(cfg, "traversal.sun_elevation_deg", lo=-90.0, hi=90.0)
    _range(cfg, "traversal.sun_azimuth_deg", lo=-360.0, hi=720.0)
    _range(cfg, "traversal.sun_illuminance_lux", lo=0.0, hi=150000.0)
    _num(cfg, "traversal.overcast_probability", lo=0.0, hi=1.0)
    _range(cfg, "traversal.sky_zenith_cd_m2", lo=0.0)
    if _get(cfg, "traversal.clear_sky") not in CLEAR_SKIES:
        raise ConfigError("world.city.traversal.clear_sky",
                          f"must be one of {', '.join(CLEAR_SKIES)}, got {_get(cfg, 'traversal.clear_sky')!r}")
    # measured clear skies: a few to ~20 kcd/m² near the horizon per 100 klux. Above 26.3 kcd/m² no sky of the CIE
    # types can have that horizon for every sun elevation (clear_sky.clear_sky_zenith_cd_m2 needs r < band/E ratio,
    # smallest 0.263 for type 13 with the sun at the zenith), so 25 kcd/m² is the cap
    _num(cfg, "traversal.clear_sky_horizon_cd_m2_per_100klux", lo=1000.0, hi=25000.0)
    _num(cfg, "traversal.vibration_deg", lo=0.0, hi=5.0)
    _num(cfg, "traversal.camera_height_m", lo=0.2, hi=4.0)
    _num(cfg, "traversal.dynamic_before_s", lo=0.0)
    _num(cfg, "traversal.dynamic_after_s", lo=0.0)
    hdri = _get(cfg, "traversal.hdri")
    if hdri is not None:
        if not isinstance(hdri, dict) or not isinstance(hdri.get("path"), str):
            raise ConfigError("world.city.traversal.hdri.path", "hdri must be null or a mapping with a 'path' string")
        if not Path(hdri["path"]).is_file():
            raise ConfigError("world.city.traversal.hdri.path", f"HDRI file not found: {hdri['path']}")
        _num(cfg, "traversal.hdri.median_cd_m2", lo=0.0, lo_open=True)
        _num(cfg, "traversal.hdri.azimuth_deg", lo=-360.0, hi=360.0)
