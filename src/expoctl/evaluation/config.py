"""Config group `evaluate` (conf/evaluate/default.yaml), validated before any work.

A *window* is a stretch of one traversal that every controller drives: `passage` windows run from `before_s` ahead
of a tunnel's entry to `after_s` past its exit (the paper's Fig. 7: entry and exit in one plot); `portal` windows
are centred on one portal crossing (entry or exit alone; long tunnels). `windows` picks which ones by index in
route order (passages: tunnel 0, 1, …; portals: entry 0, exit 0, entry 1, …), null = all.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.config_reader import Problems, Section, is_integer, param, read_config
from expoctl.controllers.base import Settings
from expoctl.controllers.registry import CONTROLLERS
from expoctl.features.registry import FRONTENDS
from expoctl.parallel import MOVED_N_JOBS
from expoctl.vo.local_map import MapTrackerConfig

ROUTE_SPLITS = ("validation", "test")
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


def _default_controllers() -> tuple[str, ...]:
    from expoctl.controllers.registry import controller_names

    return controller_names()


@dataclass(frozen=True)
class OfflineBoundParams:
    """Config `evaluate.offline_bound` (conf/evaluate/default.yaml)."""

    enabled: bool = False  # off by default: K candidates cost K² matches per frame and front end (docs/evaluation.md)
    # the grid: null takes controllers.oracle's ladder (exposures_us at 0 dB, then gains_db at the longest exposure);
    # a list gives the bound its own ladder of the same shape
    exposures_us: tuple[float, ...] | None = param(None, min=19.0, max=30000.0, unit="µs")
    gains_db: tuple[float, ...] | None = param(None, min=0.0, max=30.0, unit="dB", empty=True)
    sumlog: bool = False  # also bound the SumLog variants (<fe>_sumlog): twice the extraction and matching

    @classmethod
    def from_dict(cls, d: Any, key: str = "evaluate.offline_bound", problems=None) -> "OfflineBoundParams":
        return read_config(cls, d, key, problems)

    def check(self, r) -> None:
        if (self.exposures_us is None) != (self.gains_db is None):
            r.problem("gains_db" if self.gains_db is None else "exposures_us",
                      "give exposures_us and gains_db together (the bound's own ladder), or both null (the oracle's)")

    def candidates(self, oracle=None) -> list[Settings]:
        """The grid: this config's own ladder, or `oracle`'s (controllers.oracle's OracleParams; default its defaults)."""
        from expoctl.sim.oracle import OracleParams

        if self.exposures_us is not None:
            return OracleParams(exposures_us=self.exposures_us, gains_db=self.gains_db).candidates()
        return (oracle or OracleParams()).candidates()



@dataclass(frozen=True)
class EvaluateConfig:
    # null in the config: every registered controller (built-ins and installed plugins), in table order
    # (but opt-in ones, `rl`: expoctl.controllers.registry.controller_names; the evaluate stage adds those whose
    # stage is on)
    controllers: tuple[str, ...] = field(default_factory=lambda: _default_controllers())
    splits: dict[str, SplitPlan] = field(default_factory=dict)
    warmup_frames: int = 30
    initial_gain_db: float = 0.0
    initial_exposure_us: float = 5000.0
    sensor_randomisation: float = 0.15
    render_size: tuple[int, int] | None = None  # (width, height); None = world.render
    # true: one sharp render per frame serves every controller and oracle candidate of a window (world.render.share_render
    # for evaluate), smeared per exposure from camera 1's frame-start pose; false (default): each exposure rendered at
    # its mid-point, as collect renders the training data. true is ~2x faster but measurably further from the
    # sub-frame reference blur (docs/scale_out.md, Render once)
    share_render: bool = False
    frontends: tuple[str, ...] = field(default_factory=lambda: FRONTENDS.names())  # null: every registered one
    sumlog_pairs: int = 30
    min_section_frames: int = 10
    vo: VoConfig = VoConfig()
    thumb_width: int = 128
    thumb_every: int = 2
    thumb_span_s: float = 2.5
    # the offline optimum over a candidate grid (expoctl.evaluation.offline_bound), written to reports/eval/offline_bound.json
    offline_bound: OfflineBoundParams = OfflineBoundParams()

    @classmethod
    def from_dict(cls, d: Any, key: str = "evaluate", problems: Problems | None = None) -> "EvaluateConfig":
        r = Section(d, key, problems, required=True)
        controllers = CONTROLLERS.read_names(r, "controllers")
        if r.value("controllers", None) is None:
            controllers = _default_controllers()
        splits = r.section("splits", required=True)
        if not splits.mapping:
            splits.problem(None, f"must map route split (validation, test) → plan, got {splits.mapping!r}")
        plans = {}
        for s in ROUTE_SPLITS:
            if splits.has(s):
                plan = splits.section(s, required=True)
                plans[s] = read_split_plan(s, plan)
                plan.done()
        splits.done()
        ints = {name: r.integer(name, getattr(cls, name), min=lo) for name, lo in (
            ("warmup_frames", 0), ("sumlog_pairs", 1), ("min_section_frames", 1), ("thumb_width", 16),
            ("thumb_every", 1))}
        r.moved("n_jobs", "parallel.n_jobs", MOVED_N_JOBS)
        size = r.value("render_size", None)
        if size is not None and not (isinstance(size, (list, tuple)) and len(size) == 2
                                     and all(is_integer(v) and 16 <= v <= 8192 for v in size)):
            r.problem("render_size", f"must be [width, height] in pixels (16–8192) or null, got {size!r}")
            size = None
        fronts = FRONTENDS.read_names(r, "frontends")
        vo = r.section("vo")
        n_features = vo.integer("n_features", 2000, min=10)
        vo_cfg = VoConfig(
            min_inliers=vo.integer("min_inliers", 20, min=5),
            n_features=n_features,
            ransac_threshold_px=vo.number("ransac_threshold_px", 1.0, min=1e-3, max=100.0),
            map=read_vo_map(vo.section("map"), n_features),
        )
        vo.done()
        cfg = cls(
            controllers=controllers,
            splits=plans,
            initial_gain_db=r.number("initial_gain_db", cls.initial_gain_db, min=GAIN_DB_MIN, max=GAIN_DB_MAX),
            initial_exposure_us=r.number("initial_exposure_us", cls.initial_exposure_us, min=EXPOSURE_US_MIN,
                                         max=EXPOSURE_US_MAX),
            sensor_randomisation=r.number("sensor_randomisation", cls.sensor_randomisation, min=0.0, max=0.5),
            thumb_span_s=r.number("thumb_span_s", cls.thumb_span_s, min=0.0, max=1e6),
            render_size=None if size is None else (int(size[0]), int(size[1])),
            share_render=r.boolean("share_render", cls.share_render),
            frontends=tuple(fronts),
            vo=vo_cfg,
            offline_bound=OfflineBoundParams.from_dict(r.value("offline_bound", None), r.path("offline_bound"),
                                                       r.problems),
            **ints,
        )
        r.done()
        return cfg


def read_vo_map(r: Section, n_features: int) -> MapTrackerConfig:
    """`evaluate.vo.map`: the local-map tracker's settings (expoctl.vo.local_map); it detects vo.n_features features."""
    kw: dict = {name: r.integer(name, getattr(MapTrackerConfig, name), min=lo)
                for name, lo in MapTrackerConfig.INT_MINIMA.items() if name != "n_features"}
    lo, hi = MapTrackerConfig.SEARCH_RADIUS_RANGE_PX
    kw["search_radius_px"] = r.number("search_radius_px", MapTrackerConfig.search_radius_px, min=lo, max=hi)
    r.done()
    return MapTrackerConfig(n_features=n_features, **kw)


def read_split_plan(name: str, r: Section) -> SplitPlan:
    """A window plan's keys (`evaluate.splits.<name>`, or `select_model`'s own) from section `r`; the caller calls
    `r.done()` (the selection's section holds other keys too)."""
    windows = r.value("windows", None)
    if windows is not None:
        if isinstance(windows, str) or not isinstance(windows, (list, tuple)) or not windows or not all(
                is_integer(i) and i >= 0 for i in windows):
            r.problem("windows", f"must be a non-empty list of window indices >= 0, or null; got {windows!r}")
            windows = None
        else:
            windows = tuple(int(i) for i in windows)
    return SplitPlan(
        name=name,
        first_traversal=r.integer("first_traversal", SplitPlan.first_traversal, min=0),
        n_traversals=r.integer("n_traversals", SplitPlan.n_traversals, min=1),
        window=r.choice("window", WINDOW_MODES, SplitPlan.window),
        before_s=r.number("before_s", SplitPlan.before_s, min=0.0, max=600.0),
        after_s=r.number("after_s", SplitPlan.after_s, min=0.0, max=600.0),
        windows=windows,
    )
