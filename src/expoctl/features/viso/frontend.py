"""libviso2-style feature front end (flow / monocular case), written clean room (docs/features.md).

Pipeline per image (`extract`): half-resolution image → 5×5 Sobel du/dv (uint8), blob and corner responses → block
NMS, dense (n = nms_n) and sparse (n = 3·nms_n) → 32-byte descriptors; full-resolution du/dv for refinement.
Per pair (`match`): sparse circle-checked matching without a prior → Delaunay filter → per-cell flow prior → dense
matching with the prior → integer refinement → Delaunay filter (count A) → F-RANSAC on all matches (count C,
default) or on the bucketed matches (count B, `bucketing: true`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from time import perf_counter, process_time

import numpy as np

from expoctl.errors import InputError
from expoctl.features.registry import register_frontend
from expoctl.features.viso.descriptors import descriptors
from expoctl.features.viso.filters import blob_corner, half_resolution, sobel_du_dv
from expoctl.features.viso.match import FeatureSet, Grid, circle_match, flow_prior, make_feature_set, refine_integer
from expoctl.features.viso.nms import block_nms
from expoctl.features.viso.outliers import remove_outliers
from expoctl.features.viso.params import MARGIN, VisoParams, parse_params
from expoctl.features.viso.ransac import bucket, ransac_inlier_count


@dataclass(frozen=True)
class VisoFeatures:
    """One extracted image: dense and sparse features (full-resolution coordinates) and full-resolution gradients."""

    width: int
    height: int
    dense: FeatureSet
    sparse: FeatureSet
    du_full: np.ndarray  # uint8 H×W, for refinement
    dv_full: np.ndarray


@dataclass(frozen=True)
class VisoCounts:
    """Every intermediate count of one pair, named as in the reference numbers (reference.jsonl)."""

    n_features_1: int
    n_features_2: int
    n_features_sparse_1: int
    n_features_sparse_2: int
    n_sparse_circular: int
    n_sparse_after_outliers: int
    n_dense_circular: int
    n_dense_after_refinement: int
    n_raw_matches: int  # A
    n_bucketed: int
    n_inliers: int  # B: RANSAC on the bucketed matches
    n_inliers_nobucket: int  # C: RANSAC on all A matches

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class _Laps:
    """Accumulates seconds per pipeline stage into an optional dict (for benchmarks/viso_speed.py): wall time under
    the stage's name and process CPU time under "<stage>:cpu" (robust to other processes on a shared machine)."""

    def __init__(self, timings: dict[str, float] | None):
        self.timings = timings
        self.last = (perf_counter(), process_time())

    def lap(self, stage: str) -> None:
        now = (perf_counter(), process_time())
        if self.timings is not None:
            self.timings[stage] = self.timings.get(stage, 0.0) + (now[0] - self.last[0])
            self.timings[stage + ":cpu"] = self.timings.get(stage + ":cpu", 0.0) + (now[1] - self.last[1])
        self.last = now


def _check_grey(grey: np.ndarray) -> None:
    if not isinstance(grey, np.ndarray) or grey.ndim != 2 or grey.dtype != np.uint8:
        desc = f"{grey.dtype} array of shape {grey.shape}" if isinstance(grey, np.ndarray) else type(grey).__name__
        raise InputError(f"viso front end: expected an 8-bit grey image (H×W uint8), got {desc}")


def extract_features(grey: np.ndarray, p: VisoParams, timings: dict[str, float] | None = None) -> VisoFeatures:
    """Detect and describe features. timings, if given, accumulates seconds per stage (filters, nms, descriptors;
    see _Laps)."""
    _check_grey(grey)
    laps = _Laps(timings)
    height, width = grey.shape
    scale = 2 if p.half_resolution else 1
    img = half_resolution(grey) if p.half_resolution else grey
    du, dv = sobel_du_dv(img)
    f1, f2 = blob_corner(img)
    du_full, dv_full = (sobel_du_dv(grey) if p.half_resolution else (du, dv)) if p.refinement else (None, None)
    laps.lap("filters")
    grid = Grid(width, height, p.match_binsize)
    sets = []
    for n in (p.nms_n, p.sparse_nms_n):
        u, v, cls = block_nms(f1, f2, n, MARGIN, p.nms_tau)
        laps.lap("nms")
        desc = descriptors(du, dv, u, v)
        sets.append(make_feature_set(u * scale, v * scale, cls, desc, grid))
        laps.lap("descriptors")
    return VisoFeatures(width, height, sets[0], sets[1], du_full, dv_full)


def match_matches(
    prev: VisoFeatures, cur: VisoFeatures, p: VisoParams, timings: dict[str, float] | None = None
) -> tuple[np.ndarray, dict[str, int]]:
    """Final matches (A rows of u_prev, v_prev, u_cur, v_cur) and the intermediate match counts.

    timings, if given, accumulates seconds per stage (matching, delaunay)."""
    if (prev.width, prev.height) != (cur.width, cur.height):
        raise InputError(
            f"viso front end: image sizes differ ({prev.width}×{prev.height} vs {cur.width}×{cur.height})"
        )
    laps = _Laps(timings)
    grid = Grid(cur.width, cur.height, p.match_binsize)
    radius = p.search_radius
    counts: dict[str, int] = {}
    prior = None
    if p.multi_stage:
        sparse = circle_match(prev.sparse, cur.sparse, grid, radius, None)
        counts["n_sparse_circular"] = len(sparse)
        laps.lap("matching")
        sparse = remove_outliers(sparse, p.outlier_flow_tolerance)
        counts["n_sparse_after_outliers"] = len(sparse)
        laps.lap("delaunay")
        prior = flow_prior(sparse, grid, radius)
    dense = circle_match(prev.dense, cur.dense, grid, radius, prior)
    counts["n_dense_circular"] = len(dense)
    if p.refinement == 1:
        dense = refine_integer(dense, prev.du_full, prev.dv_full, cur.du_full, cur.dv_full, MARGIN)
    counts["n_dense_after_refinement"] = len(dense)
    laps.lap("matching")
    dense = remove_outliers(dense, p.outlier_flow_tolerance)
    counts["n_raw_matches"] = len(dense)
    laps.lap("delaunay")
    return dense, counts


def _bucketed_inliers(matches: np.ndarray, p: VisoParams, seed: int) -> tuple[int, int]:
    rng = np.random.default_rng([int(seed) % 2**64, 1])  # a stream distinct from RANSAC's
    kept = bucket(matches, p.max_features, p.bucket_width, p.bucket_height, rng)
    return len(kept), ransac_inlier_count(kept, p.ransac_iters, p.inlier_threshold, seed)


def pair_counts(prev: VisoFeatures, cur: VisoFeatures, seed: int, params: dict | VisoParams | None = None) -> VisoCounts:
    """All intermediate counts of one pair (for parity checks against the original's reference numbers)."""
    p = params if isinstance(params, VisoParams) else parse_params(params)
    matches, c = match_matches(prev, cur, p)
    n_bucketed, n_b = _bucketed_inliers(matches, p, seed)
    return VisoCounts(
        n_features_1=len(prev.dense),
        n_features_2=len(cur.dense),
        n_features_sparse_1=len(prev.sparse),
        n_features_sparse_2=len(cur.sparse),
        n_sparse_circular=c.get("n_sparse_circular", 0),
        n_sparse_after_outliers=c.get("n_sparse_after_outliers", 0),
        n_dense_circular=c["n_dense_circular"],
        n_dense_after_refinement=c["n_dense_after_refinement"],
        n_raw_matches=c["n_raw_matches"],
        n_bucketed=n_bucketed,
        n_inliers=n_b,
        n_inliers_nobucket=ransac_inlier_count(matches, p.ransac_iters, p.inlier_threshold, seed),
    )


@register_frontend("viso", config=VisoParams, label="libviso2", long_label="libviso2-style", rank=20)
class VisoFrontEnd:
    """libviso2-style front end (FrontEnd protocol). params: the `features.viso` config dict (see viso.params)."""

    name = "viso"

    def __init__(self, params: VisoParams | dict | None = None):
        self.params = params if isinstance(params, VisoParams) else parse_params(params)

    def extract(self, grey: np.ndarray, timings: dict[str, float] | None = None) -> VisoFeatures:
        return extract_features(grey, self.params, timings)

    def n_features(self, extracted: VisoFeatures) -> int:
        """Dense feature count (libviso2's n_features)."""
        return len(extracted.dense)

    def match(
        self, prev: VisoFeatures, cur: VisoFeatures, seed: int, timings: dict[str, float] | None = None
    ) -> tuple[int, int]:
        """(n_matches = A, n_inliers = C, or B when params bucketing is true). Deterministic for a given seed."""
        p = self.params
        matches, _ = match_matches(prev, cur, p, timings)
        laps = _Laps(timings)
        if p.bucketing:
            n_inliers = _bucketed_inliers(matches, p, seed)[1]
        else:
            n_inliers = ransac_inlier_count(matches, p.ransac_iters, p.inlier_threshold, seed)
        laps.lap("ransac")
        return len(matches), n_inliers
