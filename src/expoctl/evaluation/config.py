"""Config group `evaluate` (conf/evaluate/default.yaml), validated before any work.

A *window* is a stretch of one traversal that every controller drives: `passage` windows run from `before_s` ahead
of a tunnel's entry to `after_s` past its exit (the paper's Fig. 7: entry and exit in one plot); `portal` windows
are centred on one portal crossing (entry or exit alone; long tunnels). `windows` picks which ones by index in
route order (passages: tunnel 0, 1, …; portals: entry 0, exit 0, entry 1, …), null = all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.errors import ConfigError
from expoctl.vo.local_map import MapTrackerConfig

ROUTE_SPLITS = ("validation", "test")
CONTROLLER_NAMES = ("agae", "shin", "shim", "mean_intensity", "fixed", "learned", "oracle")
FRONTENDS = ("orb", "viso")
WINDOW_MODES = ("passage", "portal")


@dataclass(frozen=True)
class SplitPlan:
    """`evaluate.splits.<name>`: which traversals of world.cities.<name> and which windows of each."""

    name: str
    first_traversal: int = 0
    n_traversals: int = 1
    window: str = "passage"
    before_s: float = 4.0
    after_s: float = 4.0
    windows: tuple[int, ...] | None = None


@dataclass(frozen=True)
class VoConfig:
    min_inliers: int = 20
    n_features: int = 2000
    ransac_threshold_px: float = 1.0
    map: MapTrackerConfig = field(default_factory=MapTrackerConfig)  # its n_features is vo.n_features


@dataclass(frozen=True)
class EvaluateConfig:
    controllers: tuple[str, ...] = CONTROLLER_NAMES
    splits: dict[str, SplitPlan] = field(default_factory=dict)
    warmup_frames: int = 30
    initial_gain_db: float = 0.0
    initial_exposure_us: float = 5000.0
    sensor_randomisation: float = 0.15
    render_size: tuple[int, int] | None = None  # (width, height); None = world.render
    frontends: tuple[str, ...] = FRONTENDS
    sumlog_pairs: int = 30
    min_section_frames: int = 10
    vo: VoConfig = VoConfig()
    thumb_width: int = 128
    thumb_every: int = 2
    thumb_span_s: float = 2.5
    n_jobs: int = 1

    @classmethod
    def from_dict(cls, d: Any, key: str = "evaluate") -> "EvaluateConfig":
        if not isinstance(d, dict):
            raise ConfigError(key, f"missing or not a mapping (got {d!r})")
        known = {"controllers", "splits", "warmup_frames", "initial_gain_db", "initial_exposure_us",
                 "sensor_randomisation", "render_size", "frontends", "sumlog_pairs", "min_section_frames", "vo",
                 "thumb_width", "thumb_every", "thumb_span_s", "n_jobs"}
        _no_unknown(d, known, key)
        kw: dict = {}
        names = d.get("controllers", list(CONTROLLER_NAMES))
        if isinstance(names, str) or not isinstance(names, (list, tuple)) or not names:
            raise ConfigError(f"{key}.controllers", f"must be a non-empty list of controller names, got {names!r}")
        if len(set(names)) != len(names):
            raise ConfigError(f"{key}.controllers", f"lists a controller twice: {names!r}")
        for n in names:
            if n not in CONTROLLER_NAMES:
                raise ConfigError(f"{key}.controllers", f"unknown controller {n!r} (known: {', '.join(CONTROLLER_NAMES)})")
        kw["controllers"] = tuple(names)
        splits = d.get("splits")
        if not isinstance(splits, dict) or not splits:
            raise ConfigError(f"{key}.splits", f"must map route split (validation, test) → plan, got {splits!r}")
        _no_unknown(splits, set(ROUTE_SPLITS), f"{key}.splits")
        kw["splits"] = {s: split_plan_from_dict(s, splits[s], f"{key}.splits.{s}") for s in ROUTE_SPLITS if s in splits}
        for name, lo in (("warmup_frames", 0), ("sumlog_pairs", 1), ("min_section_frames", 1), ("thumb_width", 16),
                         ("thumb_every", 1), ("n_jobs", 1)):
            if name in d:
                kw[name] = _int(d[name], f"{key}.{name}", lo)
        if "initial_gain_db" in d:
            kw["initial_gain_db"] = _num(d["initial_gain_db"], f"{key}.initial_gain_db", GAIN_DB_MIN, GAIN_DB_MAX)
        if "initial_exposure_us" in d:
            kw["initial_exposure_us"] = _num(d["initial_exposure_us"], f"{key}.initial_exposure_us",
                                             EXPOSURE_US_MIN, EXPOSURE_US_MAX)
        if "sensor_randomisation" in d:
            kw["sensor_randomisation"] = _num(d["sensor_randomisation"], f"{key}.sensor_randomisation", 0.0, 0.5)
        if "thumb_span_s" in d:
            kw["thumb_span_s"] = _num(d["thumb_span_s"], f"{key}.thumb_span_s", 0.0, 1e6)
        rs = d.get("render_size")
        if rs is not None:
            if not (isinstance(rs, (list, tuple)) and len(rs) == 2 and all(_is_int(v) and 16 <= v <= 8192 for v in rs)):
                raise ConfigError(f"{key}.render_size", f"must be [width, height] in pixels (16–8192) or null, got {rs!r}")
            kw["render_size"] = (int(rs[0]), int(rs[1]))
        fronts = d.get("frontends", list(FRONTENDS))
        if isinstance(fronts, str) or not isinstance(fronts, (list, tuple)) or sorted(fronts) != sorted(FRONTENDS):
            # metrics.json always carries all four front-end keys (docs/evaluation.md), so both front ends always run
            raise ConfigError(f"{key}.frontends", f"must list both front ends {list(FRONTENDS)}, got {fronts!r}")
        kw["frontends"] = tuple(fronts)
        vo = d.get("vo") or {}
        if not isinstance(vo, dict):
            raise ConfigError(f"{key}.vo", f"must be a mapping, got {vo!r}")
        _no_unknown(vo, {"min_inliers", "n_features", "ransac_threshold_px", "map"}, f"{key}.vo")
        n_features = _int(vo.get("n_features", 2000), f"{key}.vo.n_features", 10)
        kw["vo"] = VoConfig(
            min_inliers=_int(vo.get("min_inliers", 20), f"{key}.vo.min_inliers", 5),
            n_features=n_features,
            ransac_threshold_px=_num(vo.get("ransac_threshold_px", 1.0), f"{key}.vo.ransac_threshold_px", 1e-3, 100.0),
            map=vo_map_config_from_dict(vo.get("map") or {}, f"{key}.vo.map", n_features),
        )
        return cls(**kw)


def vo_map_config_from_dict(d: Any, key: str, n_features: int) -> MapTrackerConfig:
    """`evaluate.vo.map`: the local-map tracker's settings (expoctl.vo.local_map); it detects vo.n_features features."""
    if not isinstance(d, dict):
        raise ConfigError(key, f"must be a mapping, got {d!r}")
    _no_unknown(d, set(MapTrackerConfig.__dataclass_fields__) - {"n_features"}, key)
    kw: dict = {name: _int(d[name], f"{key}.{name}", lo)
                for name, lo in MapTrackerConfig.INT_MINIMA.items() if name in d}
    if "search_radius_px" in d:
        kw["search_radius_px"] = _num(d["search_radius_px"], f"{key}.search_radius_px",
                                      *MapTrackerConfig.SEARCH_RADIUS_RANGE_PX)
    return MapTrackerConfig(n_features=n_features, **kw)


def split_plan_from_dict(name: str, d: Any, key: str) -> SplitPlan:
    """A window plan (`evaluate.splits.<name>`, or `select_model`'s own) from its mapping at config key `key`."""
    if not isinstance(d, dict):
        raise ConfigError(key, f"must be a mapping, got {d!r}")
    _no_unknown(d, {"first_traversal", "n_traversals", "window", "before_s", "after_s", "windows"}, key)
    kw: dict = {"name": name}
    if "first_traversal" in d:
        kw["first_traversal"] = _int(d["first_traversal"], f"{key}.first_traversal", 0)
    if "n_traversals" in d:
        kw["n_traversals"] = _int(d["n_traversals"], f"{key}.n_traversals", 1)
    if "window" in d:
        if d["window"] not in WINDOW_MODES:
            raise ConfigError(f"{key}.window", f"must be one of {WINDOW_MODES}, got {d['window']!r}")
        kw["window"] = d["window"]
    for k in ("before_s", "after_s"):
        if k in d:
            kw[k] = _num(d[k], f"{key}.{k}", 0.0, 600.0)
    w = d.get("windows")
    if w is not None:
        if isinstance(w, str) or not isinstance(w, (list, tuple)) or not w or not all(_is_int(i) and i >= 0 for i in w):
            raise ConfigError(f"{key}.windows", f"must be a non-empty list of window indices >= 0, or null; got {w!r}")
        kw["windows"] = tuple(int(i) for i in w)
    return SplitPlan(**kw)


def _no_unknown(d: dict, known: set[str], key: str) -> None:
    for k in d:
        if k not in known:
            raise ConfigError(f"{key}.{k}", f"unknown key (expected one of {sorted(known)})")


def _is_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _int(v, key: str, lo: int) -> int:
    if not _is_int(v) or v < lo:
        raise ConfigError(key, f"must be an integer >= {lo}, got {v!r}")
    return int(v)


def _num(v, key: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ConfigError(key, f"must be a number in [{lo}, {hi}], got {v!r}")
    return float(v)
