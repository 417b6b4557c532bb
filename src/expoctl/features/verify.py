"""Geometric verification of putative matches: fundamental-matrix RANSAC (the paper's "inlier matches", NFM).

A match is an inlier when both points lie within `threshold_px` of the epipolar line the estimated fundamental
matrix F assigns them (OpenCV's error is max(d₁², d₂²) against threshold², i.e. the larger of the two point-to-line
distances). Defaults (docs/features.md, Geometric verification): 3 px, confidence 0.99.

Determinism: OpenCV's classic FM_RANSAC samples with a fixed internal RNG (cv2.setRNGSeed has no effect on it), so we
make the seed matter by presenting the correspondences in a seed-determined order (the sampler draws indices, so a
permutation changes which minimal sets it draws). The USAC variants take the seed as `randomGeneratorState`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from expoctl.errors import ConfigError

#: below this many correspondences no fundamental matrix can be estimated by the 8-point RANSAC
MIN_CORRESPONDENCES = 8

_METHODS = ("ransac", "usac")


@dataclass(frozen=True)
class VerifyParams:
    threshold_px: float = 3.0
    confidence: float = 0.99
    max_iters: int = 1000  # OpenCV's default for findFundamentalMat (what a plain call uses)
    method: str = "ransac"  # ransac (classic cv2.FM_RANSAC) | usac (cv2.UsacParams defaults: MSAC score, LO)

    def __post_init__(self):
        if not (self.threshold_px > 0):
            raise ConfigError("features.orb.ransac_threshold_px", f"must be > 0, got {self.threshold_px}")
        if not (0 < self.confidence < 1):
            raise ConfigError("features.orb.ransac_confidence", f"must be in (0, 1), got {self.confidence}")
        if int(self.max_iters) < 1:
            raise ConfigError("features.orb.ransac_max_iters", f"must be >= 1, got {self.max_iters}")
        if self.method not in _METHODS:
            raise ConfigError("features.orb.ransac_method", f"must be one of {sorted(_METHODS)}, got {self.method!r}")


def fundamental_inlier_mask(
    pts_prev: np.ndarray, pts_cur: np.ndarray, seed: int = 0, params: VerifyParams = VerifyParams()
) -> np.ndarray:
    """Boolean mask (N,) of correspondences consistent with one fundamental matrix.

    pts_prev, pts_cur: (N, 2) pixel coordinates of matched points. Fewer than 8 correspondences, or a degenerate
    configuration for which OpenCV finds no F (all points identical or collinear), give an all-False mask.
    """
    p1 = np.asarray(pts_prev, dtype=np.float64).reshape(-1, 2)
    p2 = np.asarray(pts_cur, dtype=np.float64).reshape(-1, 2)
    if p1.shape != p2.shape:
        raise ValueError(f"point arrays differ in shape: {p1.shape} vs {p2.shape}")
    n = len(p1)
    mask = np.zeros(n, dtype=bool)
    if n < MIN_CORRESPONDENCES:
        return mask
    order = np.random.default_rng(seed).permutation(n)
    a = np.ascontiguousarray(p1[order])
    b = np.ascontiguousarray(p2[order])
    if params.method == "ransac":
        cv2.setRNGSeed(int(seed) & 0x7FFFFFFF)
        F, m = cv2.findFundamentalMat(a, b, cv2.FM_RANSAC, params.threshold_px, params.confidence, params.max_iters)
    else:
        usac = cv2.UsacParams()
        usac.threshold = params.threshold_px
        usac.confidence = params.confidence
        usac.maxIterations = int(params.max_iters)
        usac.randomGeneratorState = int(seed) & 0x7FFFFFFF
        try:
            F, m = cv2.findFundamentalMat(a, b, usac)
        except cv2.error:
            # USAC raises (instead of returning None) when every sample is degenerate
            return mask
    # With no F found OpenCV returns an uninitialised mask: never read it then.
    if F is None or m is None or F.shape != (3, 3):
        return mask
    mask[order] = m.ravel() != 0
    return mask


def count_fundamental_inliers(
    pts_prev: np.ndarray, pts_cur: np.ndarray, seed: int = 0, params: VerifyParams = VerifyParams()
) -> int:
    """Number of correspondences consistent with one fundamental matrix (0 for fewer than 8)."""
    return int(fundamental_inlier_mask(pts_prev, pts_cur, seed, params).sum())
