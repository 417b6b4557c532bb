"""ORB front end (OpenCV), as the paper's authors ran it.

The authors converted each image to 512×384 grey and used two ORB detectors: one with nfeatures = 10000 whose
keypoint count is the image's feature count (M_feat), and one with nfeatures = 2000 whose keypoints are described
and matched (M_match, NFM). Matching is brute-force Hamming with cross-check (mutual nearest neighbours), then
fundamental-matrix RANSAC (verify.py, 3 px at the working size, confidence 0.99).

The cross-checked brute-force matcher is our own (numba): OpenCV 5's BFMatcher spends ~200 ms on a 2000×2000
Hamming cross-check, ours ~40 ms with the same result (same distances, first index wins ties in both directions).

Both detectors run on the same resized image. Resizing both images of a pair by the same factors keeps the epipolar
geometry valid (a scaling is a projective map), so verifying at the working size is sound.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba
import numpy as np

from expoctl.config_reader import Problems, Section, is_integer, read_config
from expoctl.features.registry import register_frontend
from expoctl.features.verify import VerifyParams, count_fundamental_inliers


@dataclass(frozen=True)
class OrbParams:
    working_size: tuple[int, int] | None = (512, 384)  # (width, height) px images are resized to; None = native
    count_nfeatures: int = 10000  # detector whose keypoint count is the feature count
    match_nfeatures: int = 2000  # detector whose keypoints are described and matched
    scale_factor: float = 1.2  # OpenCV defaults from here on
    n_levels: int = 8
    edge_threshold: int = 31
    patch_size: int = 31
    fast_threshold: int = 20
    ransac_threshold_px: float = 3.0
    ransac_confidence: float = 0.99
    ransac_max_iters: int = 1000
    ransac_method: str = "ransac"

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "features.orb", problems: Problems | None = None) -> "OrbParams":
        """Build from a config dict (missing keys take the defaults above); every problem at once (ConfigError)."""
        return read_config(cls, d, key, problems)

    @classmethod
    def from_section(cls, r: Section) -> "OrbParams":
        """The keys of section `r` (`features.orb`); the caller calls `r.done()`."""
        ws = r.value("working_size", cls.working_size)
        if ws is not None:
            if not (isinstance(ws, (list, tuple)) and len(ws) == 2 and all(is_integer(v) and v >= 32 for v in ws)):
                r.problem("working_size", f"must be [width, height] with both >= 32, or null; got {ws!r}")
                ws = cls.working_size
            ws = (int(ws[0]), int(ws[1]))
        positive = {name: r.integer(name, getattr(cls, name), min=1) for name in (
            "count_nfeatures", "match_nfeatures", "n_levels", "edge_threshold", "patch_size", "ransac_max_iters")}
        params = cls(
            working_size=ws,
            scale_factor=r.number("scale_factor", cls.scale_factor, above=1),
            fast_threshold=r.integer("fast_threshold", cls.fast_threshold, min=0, max=255),
            # the RANSAC keys' bounds are VerifyParams' (checked below, with the others' problems)
            ransac_threshold_px=r.number("ransac_threshold_px", cls.ransac_threshold_px),
            ransac_confidence=r.number("ransac_confidence", cls.ransac_confidence),
            ransac_method=r.text("ransac_method", cls.ransac_method),
            **positive,
        )
        r.problems.collect(params.verify_params)
        return params

    def verify_params(self) -> VerifyParams:
        return VerifyParams(
            threshold_px=float(self.ransac_threshold_px),
            confidence=float(self.ransac_confidence),
            max_iters=int(self.ransac_max_iters),
            method=self.ransac_method,
        )


@dataclass(frozen=True)
class OrbFeatures:
    """One image's extraction: the count detector's keypoint count and the match detector's keypoints."""

    n_count: int
    points_xy: np.ndarray  # (N, 2) float32 keypoint positions at the working size
    descriptors: np.ndarray  # (N, 32) uint8 binary descriptors


@register_frontend("orb", config=OrbParams, label="ORB", rank=10)
class OrbFrontEnd:
    """FrontEnd (see frontend.py) using OpenCV ORB; `params` is an OrbParams or a config dict."""

    name = "orb"

    def __init__(self, params: OrbParams | dict | None = None):
        self.params = params if isinstance(params, OrbParams) else OrbParams.from_dict(params)
        self._verify = self.params.verify_params()
        p = self.params
        common = dict(
            scaleFactor=float(p.scale_factor),
            nlevels=int(p.n_levels),
            edgeThreshold=int(p.edge_threshold),
            patchSize=int(p.patch_size),
            fastThreshold=int(p.fast_threshold),
        )
        self._count_orb = cv2.ORB_create(nfeatures=int(p.count_nfeatures), **common)
        self._match_orb = cv2.ORB_create(nfeatures=int(p.match_nfeatures), **common)

    def prepare(self, grey: np.ndarray) -> np.ndarray:
        """The image the detectors see: grey resized to the working size (area averaging when shrinking)."""
        if grey.ndim != 2 or grey.dtype != np.uint8:
            raise ValueError(f"ORB expects an H×W uint8 grey image, got shape {grey.shape} dtype {grey.dtype}")
        ws = self.params.working_size
        if ws is None or (grey.shape[1], grey.shape[0]) == ws:
            return grey
        shrinking = ws[0] * ws[1] < grey.shape[0] * grey.shape[1]
        return cv2.resize(grey, ws, interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)

    def extract(self, grey: np.ndarray) -> OrbFeatures:
        img = self.prepare(grey)
        n_count = len(self._count_orb.detect(img, None))
        keypoints, descriptors = self._match_orb.detectAndCompute(img, None)
        if descriptors is None or len(keypoints) == 0:
            return OrbFeatures(n_count, np.zeros((0, 2), np.float32), np.zeros((0, 32), np.uint8))
        points = np.array([kp.pt for kp in keypoints], dtype=np.float32).reshape(-1, 2)
        return OrbFeatures(n_count, points, descriptors)

    def n_features(self, extracted: OrbFeatures) -> int:
        return int(extracted.n_count)

    def match(self, prev: OrbFeatures, cur: OrbFeatures, seed: int) -> tuple[int, int]:
        if len(prev.descriptors) == 0 or len(cur.descriptors) == 0:
            return 0, 0
        idx_prev, idx_cur = hamming_mutual_matches(prev.descriptors, cur.descriptors)
        n_inliers = count_fundamental_inliers(prev.points_xy[idx_prev], cur.points_xy[idx_cur], seed, self._verify)
        return len(idx_prev), n_inliers


def hamming_mutual_matches(desc_a: np.ndarray, desc_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cross-checked brute-force Hamming matching of binary descriptors (N×B and M×B uint8).

    Returns (idx_a, idx_b): pairs that are each other's nearest neighbour, in increasing idx_a. Ties go to the lower
    index in both directions (as OpenCV's BFMatcher with crossCheck=True).
    """
    if desc_a.ndim != 2 or desc_b.ndim != 2 or desc_a.shape[1] != desc_b.shape[1]:
        raise ValueError(f"descriptor arrays must be N×B and M×B, got {desc_a.shape} and {desc_b.shape}")
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return _mutual_nearest(_as_words(desc_a), _as_words(desc_b))


def _as_words(desc: np.ndarray) -> np.ndarray:
    """uint8 rows → uint64 words (zero padding to a multiple of 8 bytes does not change Hamming distances)."""
    desc = np.ascontiguousarray(desc, dtype=np.uint8)
    pad = (-desc.shape[1]) % 8
    if pad:
        desc = np.concatenate([desc, np.zeros((len(desc), pad), np.uint8)], axis=1)
    return desc.view(np.uint64)


@numba.njit(cache=True, inline="always")
def _popcount64(x):
    # SWAR bit count; LLVM turns this idiom into the POPCNT instruction where the CPU has it
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (x * np.uint64(0x0101010101010101)) >> np.uint64(56)


@numba.njit(cache=True, boundscheck=False)
def _mutual_nearest(a, b):
    n, m, w = a.shape[0], b.shape[0], a.shape[1]
    col_best = np.full(m, 1 << 30, np.int64)
    col_idx = np.full(m, -1, np.int64)
    row_idx = np.full(n, -1, np.int64)
    for i in range(n):  # one pass over the distance matrix updates both directions' nearest neighbours
        row_best = 1 << 30
        for j in range(m):
            d = 0
            for k in range(w):
                d += np.int64(_popcount64(a[i, k] ^ b[j, k]))
            if d < row_best:
                row_best = d
                row_idx[i] = j
            if d < col_best[j]:
                col_best[j] = d
                col_idx[j] = i
    count = 0
    for i in range(n):
        if col_idx[row_idx[i]] == i:
            count += 1
    idx_a = np.empty(count, np.int64)
    idx_b = np.empty(count, np.int64)
    c = 0
    for i in range(n):
        if col_idx[row_idx[i]] == i:
            idx_a[c] = i
            idx_b[c] = row_idx[i]
            c += 1
    return idx_a, idx_b
