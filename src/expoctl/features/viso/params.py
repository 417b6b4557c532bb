"""Parameters of the libviso2-style matcher (flow / monocular case), with validation.

Names follow libviso2's own parameter names (as in docs/features.md, Parameters, and the `params` field of the
reference numbers), so a reference run maps onto this dict one to one. Distances are in full-resolution pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

from expoctl.config_reader import Section, is_integer, read_config
from expoctl.errors import ConfigError

#: Border (in pixels at matching resolution) inside which no feature is detected; libviso2 fixes it to 8+1.
MARGIN = 9

@dataclass(frozen=True)
class VisoParams:
    nms_n: int = 3  # NMS block size n: blocks (n+1)², search window (2n+1)²
    nms_tau: int = 50  # response threshold
    match_binsize: int = 50  # lookup bins and the prior's grid (px)
    match_radius: int = 200  # search half-window (px); halved with half_resolution, as libviso2 does
    outlier_flow_tolerance: float = 5.0  # Delaunay filter: L1 flow difference along an edge (px)
    multi_stage: bool = True  # sparse pass, then dense pass with a prior
    half_resolution: bool = True  # detect/match at half resolution, refine at full resolution
    refinement: int = 1  # 0 none, 1 integer-pixel (sub-pixel, 2, is not implemented)
    bucketing: bool = False  # False: n_inliers = count C (RANSAC on all matches); True: count B (bucketed)
    max_features: int = 2  # per bucket (bucketing only)
    bucket_width: int = 50  # px
    bucket_height: int = 50  # px
    ransac_iters: int = 2000
    inlier_threshold: float = 1e-5  # Sampson error in Hartley-normalised coordinates

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "features.viso", problems=None) -> "VisoParams":
        """Every problem at once (ConfigError), each under its own key (`config_reader.read_config`)."""
        return read_config(cls, d, key, problems)

    @classmethod
    def from_section(cls, r: Section) -> "VisoParams":
        """The keys of section `r` (`features.viso`; libviso2's 0/1 switches accepted); the caller calls `done()`."""
        return _read_viso(r)

    @property
    def sparse_nms_n(self) -> int:
        """Block size of the sparse (first-stage) NMS: 3n, or max(n, 10) when 3n exceeds 10."""
        n_s = 3 * self.nms_n
        return max(self.nms_n, 10) if n_s > 10 else n_s

    @property
    def search_radius(self) -> float:
        """Half-window of the search without a prior, in full-resolution pixels (libviso2 halves it at half res)."""
        return self.match_radius / 2 if self.half_resolution else float(self.match_radius)


def _flag(r: Section, name: str) -> bool:
    # libviso2 spells its switches as 0/1; accept those as well as YAML booleans
    value = r.value(name, getattr(VisoParams, name))
    if isinstance(value, bool):
        return value
    if is_integer(value) and value in (0, 1):
        return bool(value)
    r.problem(name, f"must be true/false (or 0/1), got {value!r}")
    return getattr(VisoParams, name)


def parse_params(params: dict | None) -> VisoParams:
    """Validate a `features.viso` config dict (missing keys take defaults) and return VisoParams; every problem at
    once (ConfigError)."""
    return VisoParams.from_dict(params)


def _read_viso(r: Section) -> VisoParams:
    """The keys of section `r` (`features.viso`); the caller calls `r.done()`."""
    d = VisoParams
    refinement = r.integer("refinement", d.refinement, min=0, max=2)
    if refinement == 2:
        r.problem("refinement", "2 (sub-pixel) is not implemented; use 0 (none) or 1 (integer pixel)")
    out = VisoParams(
        nms_n=r.integer("nms_n", d.nms_n, min=1),
        nms_tau=r.integer("nms_tau", d.nms_tau, min=0),
        match_binsize=r.integer("match_binsize", d.match_binsize, min=1),
        match_radius=r.integer("match_radius", d.match_radius, min=1),
        outlier_flow_tolerance=r.number("outlier_flow_tolerance", d.outlier_flow_tolerance, above=0),
        multi_stage=_flag(r, "multi_stage"),
        half_resolution=_flag(r, "half_resolution"),
        refinement=refinement,
        bucketing=_flag(r, "bucketing"),
        max_features=r.integer("max_features", d.max_features, min=1),
        bucket_width=r.integer("bucket_width", d.bucket_width, min=1),
        bucket_height=r.integer("bucket_height", d.bucket_height, min=1),
        ransac_iters=r.integer("ransac_iters", d.ransac_iters, min=1),
        inlier_threshold=r.number("inlier_threshold", d.inlier_threshold, above=0),
    )
    return out

