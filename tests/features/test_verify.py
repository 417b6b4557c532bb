"""Fundamental-matrix verification on synthetic two-view geometry with known inliers and outliers."""

import numpy as np
import pytest

from expoctl.errors import ConfigError
from expoctl.features.verify import VerifyParams, count_fundamental_inliers, fundamental_inlier_mask

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
W, H = 640, 480


def _rotation(rx, ry, rz):
    cx, sx, cy, sy, cz, sz = np.cos(rx), np.sin(rx), np.cos(ry), np.sin(ry), np.cos(rz), np.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _project(X, R, t):
    x = (K @ (R @ X.T + t[:, None])).T
    return x[:, :2] / x[:, 2:3], x[:, 2]


def _epipolar_distance(F, p1, p2):
    """max of the two point-to-epipolar-line distances (the error OpenCV compares with the threshold)."""
    h1 = np.c_[p1, np.ones(len(p1))]
    h2 = np.c_[p2, np.ones(len(p2))]
    l2 = h1 @ F.T  # lines in image 2
    l1 = h2 @ F  # lines in image 1
    d2 = np.abs(np.sum(l2 * h2, 1)) / np.hypot(l2[:, 0], l2[:, 1])
    d1 = np.abs(np.sum(l1 * h1, 1)) / np.hypot(l1[:, 0], l1[:, 1])
    return np.maximum(d1, d2)


def _scene(seed, n_points=300, n_outliers=150, noise_px=0.3):
    """Two views of random 3D points; returns points, truth labels and the true F.

    The baseline has a strong sideways part and the points a wide depth range, so F is well determined: every F that
    fits the inliers to within the threshold is close to the true one all over the image, and "far from the true
    epipolar line" is a sound definition of an outlier. (Pure forward motion over distant points leaves F poorly
    constrained away from the points, and a correct RANSAC may then accept outliers the true F would reject.)
    """
    rng = np.random.default_rng(seed)
    X = np.c_[rng.uniform(-6, 6, 3 * n_points), rng.uniform(-4, 4, 3 * n_points), rng.uniform(3, 15, 3 * n_points)]
    R = _rotation(*rng.uniform(-0.05, 0.05, 3))
    t = np.array([-1.0, rng.uniform(-0.2, 0.2), rng.uniform(-0.5, 0.5)])
    p1, z1 = _project(X, np.eye(3), np.zeros(3))
    p2, z2 = _project(X, R, t)
    visible = (z1 > 0) & (z2 > 0) & np.all((p1 >= 0) & (p1 < [W, H]) & (p2 >= 0) & (p2 < [W, H]), axis=1)
    p1, p2 = p1[visible][:n_points], p2[visible][:n_points]
    assert len(p1) == n_points
    p1 = p1 + rng.normal(0, noise_px, p1.shape)
    p2 = p2 + rng.normal(0, noise_px, p2.shape)
    # outliers: a real point in image 1 paired with an unrelated position in image 2 (a wrong descriptor match)
    o1 = rng.uniform([0, 0], [W, H], (n_outliers, 2))
    o2 = rng.uniform([0, 0], [W, H], (n_outliers, 2))
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Kinv = np.linalg.inv(K)
    F_true = Kinv.T @ tx @ R @ Kinv
    is_inlier = np.r_[np.ones(n_points, bool), np.zeros(n_outliers, bool)]
    return np.r_[p1, o1], np.r_[p2, o2], is_inlier, F_true


SEEDS = range(9)


def _run(method):
    recovered, accepted_outliers, n_true, n_out = [], [], 0, 0
    for seed in SEEDS:
        pts1, pts2, is_inlier, _ = _scene(seed)
        params = VerifyParams(method=method)
        mask = fundamental_inlier_mask(pts1, pts2, seed=seed, params=params)
        assert count_fundamental_inliers(pts1, pts2, seed=seed, params=params) == mask.sum()
        recovered.append(int(mask[is_inlier].sum()))
        accepted_outliers.append(int(mask[~is_inlier].sum()))
        n_true, n_out = int(is_inlier.sum()), int((~is_inlier).sum())
    return np.array(recovered), np.array(accepted_outliers), n_true, n_out


# Outliers: a random wrong match falls inside the ±3 px band around its epipolar line with probability about
# 2·3/480 ≈ 1.25 % (lines are nearly horizontal here), and RANSAC keeps the model with the most inliers, which may tilt
# within the threshold slack to take in a few more: expect ~2.5 % (3.75 of 150, binomial sd ~1.9). Allow 6 %.
MAX_ACCEPTED_OUTLIER_FRACTION = 0.06


def test_classic_ransac_recovers_inliers_and_rejects_outliers():
    recovered, accepted, n_true, n_out = _run("ransac")
    # Inlier noise (0.3 px) is 10x below the threshold, so each true inlier fits the true F. Classic RANSAC returns
    # the best model among 8-point fits to *minimal* noisy samples (no local optimisation); such a fit can tilt
    # enough to drop inliers near the image borders. Over these seeds it keeps ≥ 98 % in the median and never
    # loses more than 15 % (measured over 60 seeds: median 98.8 %, worst 86 %).
    assert np.median(recovered) >= 0.98 * n_true
    assert recovered.min() >= 0.85 * n_true
    assert accepted.max() <= MAX_ACCEPTED_OUTLIER_FRACTION * n_out


def test_usac_recovers_inliers_and_rejects_outliers():
    recovered, accepted, n_true, n_out = _run("usac")
    # USAC refines each good model on its inliers (local optimisation), so the minimal-sample tilt is gone:
    # 2 % tolerance covers the rare inlier whose 0.3 px noise plus the fit's residual error approaches 3 px.
    assert recovered.min() >= n_true - int(0.02 * n_true)
    assert accepted.max() <= MAX_ACCEPTED_OUTLIER_FRACTION * n_out


def test_seed_changes_the_sample_order_not_the_answer_much():
    pts1, pts2, is_inlier, _ = _scene(11, noise_px=1.0)
    counts = {seed: count_fundamental_inliers(pts1, pts2, seed=seed) for seed in range(4)}
    assert len(set(counts.values())) > 1  # the seed reaches the sampler (classic FM_RANSAC ignores cv2.setRNGSeed)
    assert max(counts.values()) - min(counts.values()) <= 0.2 * is_inlier.sum()


def test_deterministic_for_a_seed():
    pts1, pts2, _, _ = _scene(7, noise_px=1.0)
    a = fundamental_inlier_mask(pts1, pts2, seed=3)
    b = fundamental_inlier_mask(pts1, pts2, seed=3)
    assert np.array_equal(a, b)


def test_fewer_than_eight_matches_give_zero():
    pts1, pts2, _, _ = _scene(0, n_points=7, n_outliers=0)
    assert count_fundamental_inliers(pts1, pts2) == 0
    assert count_fundamental_inliers(np.zeros((0, 2)), np.zeros((0, 2))) == 0


def test_degenerate_configuration_gives_zero_not_garbage():
    # All points identical: OpenCV finds no F and returns an uninitialised mask, which must not be read.
    same = np.full((50, 2), 100.0)
    assert count_fundamental_inliers(same, same) == 0


def test_bad_parameters_are_config_errors():
    with pytest.raises(ConfigError, match="ransac_threshold_px"):
        VerifyParams(threshold_px=0)
    with pytest.raises(ConfigError, match="ransac_confidence"):
        VerifyParams(confidence=1.0)
    with pytest.raises(ConfigError, match="ransac_method"):
        VerifyParams(method="lmeds")
