"""Parameters of the libviso2-style matcher (flow / monocular case), with validation.

Names follow libviso2's own parameter names (as in docs/features.md, Parameters, and the `params` field of the
reference numbers), so a reference run maps onto this dict one to one. Distances are in full-resolution pixels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from expoctl.errors import ConfigError

#: Border (in pixels at matching resolution) inside which no feature is detected; libviso2 fixes it to 8+1.
MARGIN = 9

_DEFAULTS: dict[str, Any] = {
    "nms_n": 3,  # NMS block size n: blocks (n+1)², search window (2n+1)²
    "nms_tau": 50,  # response threshold
    "match_binsize": 50,  # lookup bins and the prior's grid (px)
    "match_radius": 200,  # search half-window (px); halved with half_resolution, as libviso2 does
    "outlier_flow_tolerance": 5,  # Delaunay filter: L1 flow difference along an edge (px)
    "multi_stage": True,  # sparse pass, then dense pass with a prior
    "half_resolution": True,  # detect/match at half resolution, refine at full resolution
    "refinement": 1,  # 0 none, 1 integer-pixel (sub-pixel, 2, is not implemented)
    "bucketing": False,  # False: n_inliers = count C (RANSAC on all matches); True: count B (bucketed)
    "max_features": 2,  # per bucket (bucketing only)
    "bucket_width": 50,  # px
    "bucket_height": 50,  # px
    "ransac_iters": 2000,
    "inlier_threshold": 1e-5,  # Sampson error in Hartley-normalised coordinates
}


@dataclass(frozen=True)
class VisoParams:
    nms_n: int = 3
    nms_tau: int = 50
    match_binsize: int = 50
    match_radius: int = 200
    outlier_flow_tolerance: float = 5.0
    multi_stage: bool = True
    half_resolution: bool = True
    refinement: int = 1
    bucketing: bool = False
    max_features: int = 2
    bucket_width: int = 50
    bucket_height: int = 50
    ransac_iters: int = 2000
    inlier_threshold: float = 1e-5

    @property
    def sparse_nms_n(self) -> int:
        """Block size of the sparse (first-stage) NMS: 3n, or max(n, 10) when 3n exceeds 10."""
        n_s = 3 * self.nms_n
        return max(self.nms_n, 10) if n_s > 10 else n_s

    @property
    def search_radius(self) -> float:
        """Half-window of the search without a prior, in full-resolution pixels (libviso2 halves it at half res)."""
        return self.match_radius / 2 if self.half_resolution else float(self.match_radius)


def _key(name: str) -> str:
    return f"features.viso.{name}"


def _int(name: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(_key(name), f"must be an integer, got {value!r}")
    if value < minimum:
        raise ConfigError(_key(name), f"must be >= {minimum}, got {value}")
    return value


def _positive(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 or value != value:
        raise ConfigError(_key(name), f"must be a positive number, got {value!r}")
    return float(value)


def _flag(name: str, value: Any) -> bool:
    # libviso2 spells its switches as 0/1; accept those as well as YAML booleans
    if isinstance(value, bool):
        return value
    if isinstance(value, int) and value in (0, 1):
        return bool(value)
    raise ConfigError(_key(name), f"must be true/false (or 0/1), got {value!r}")


def parse_params(params: dict | None) -> VisoParams:
    """Validate a `features.viso` config dict (missing keys take defaults) and return VisoParams."""
    if params is None:
        params = {}
    if not isinstance(params, dict):
        raise ConfigError("features.viso", f"must be a mapping, got {type(params).__name__}")
    unknown = sorted(set(params) - set(_DEFAULTS))
    if unknown:
        raise ConfigError(_key(unknown[0]), f"unknown key (known: {', '.join(sorted(_DEFAULTS))})")
    p = {**_DEFAULTS, **params}
    refinement = _int("refinement", p["refinement"], 0)
    if refinement == 2:
        raise ConfigError(_key("refinement"), "2 (sub-pixel) is not implemented; use 0 (none) or 1 (integer pixel)")
    if refinement > 2:
        raise ConfigError(_key("refinement"), f"must be 0 or 1, got {refinement}")
    return VisoParams(
        nms_n=_int("nms_n", p["nms_n"], 1),
        nms_tau=_int("nms_tau", p["nms_tau"], 0),
        match_binsize=_int("match_binsize", p["match_binsize"], 1),
        match_radius=_int("match_radius", p["match_radius"], 1),
        outlier_flow_tolerance=_positive("outlier_flow_tolerance", p["outlier_flow_tolerance"]),
        multi_stage=_flag("multi_stage", p["multi_stage"]),
        half_resolution=_flag("half_resolution", p["half_resolution"]),
        refinement=refinement,
        bucketing=_flag("bucketing", p["bucketing"]),
        max_features=_int("max_features", p["max_features"], 1),
        bucket_width=_int("bucket_width", p["bucket_width"], 1),
        bucket_height=_int("bucket_height", p["bucket_height"], 1),
        ransac_iters=_int("ransac_iters", p["ransac_iters"], 1),
        inlier_threshold=_positive("inlier_threshold", p["inlier_threshold"]),
    )
