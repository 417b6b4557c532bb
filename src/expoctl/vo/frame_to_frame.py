"""Monocular frame-to-frame visual odometry for the tracking-success test (docs/evaluation.md, Tracking-success test).

Per consecutive pair: ORB features (OpenCV), brute-force Hamming matching with cross-check (the project's numba
matcher, `expoctl.features.orb.hamming_mutual_matches`: OpenCV's BFMatcher list in the same order, one distance pass
instead of two), essential matrix by RANSAC (cv2.findEssentialMat, known intrinsics K), relative pose by
cv2.recoverPose. The tracked-inlier count of a pair is the number of matches consistent with the essential matrix
(RANSAC inliers, `ransac_threshold_px`).
A run FAILS at the first frame whose pair with the previous frame has fewer than `min_inliers` tracked
inliers (ORB-SLAM2 loses track below roughly 15–20 matches); counts are still computed for every later pair so the
whole run can be plotted, but the trajectory stops being meaningful there.

Scale: monocular VO recovers translation only up to scale — the scale is unobservable from images alone. With
ground-truth poses, each step's translation is scaled to the ground-truth step length (the usual "scale from GT"
protocol for monocular error metrics); without them every step has unit length. Trajectory errors therefore
measure rotation and direction of travel, not scale drift.
ATE: RMSE of camera positions after a rigid (rotation + translation, no scale) Umeyama alignment to ground truth,
over the tracked prefix (frames before the failure). RPE: RMSE over consecutive pairs of the relative-pose error's
translation (m) and rotation angle (degrees), same prefix.
Poses are 4×4 camera-to-world matrices (T_wc), camera frame x right, y down, z forward (OpenCV).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

from expoctl.errors import InputError
from expoctl.features.orb import hamming_mutual_matches


@dataclass
class TrackingResult:
    """Outcome of `track_sequence`.

    success: no pair fell below `min_inliers`. failed_at_frame: index of the first frame that lost track (None if
    success). n_inliers: int array of length n_frames − 1, entry j for the pair (frame j, frame j + 1).
    trajectory: (n_frames, 4, 4) estimated T_wc (starts at the first ground-truth pose, else identity).
    ate_m / rpe: trajectory errors over the tracked prefix (None without ground truth or with < 2 tracked frames);
    rpe = {"trans_m": RMSE, "rot_deg": RMSE}."""

    success: bool
    failed_at_frame: int | None
    n_inliers: np.ndarray
    trajectory: np.ndarray
    ate_m: float | None = None
    rpe: dict | None = None
    n_matches: np.ndarray = field(default_factory=lambda: np.zeros(0, int))


def intrinsics_matrix(intrinsics: dict, scale: float = 1.0) -> np.ndarray:
    """K from a raw sequence's `rig.intrinsics` {fx, fy, cx, cy} (pixels), optionally for images resized by
    `scale` (pixel-centre convention: c' = (c + 0.5)·scale − 0.5)."""
    try:
        fx, fy, cx, cy = (float(intrinsics[k]) for k in ("fx", "fy", "cx", "cy"))
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"vo: rig.intrinsics must have numeric fx, fy, cx, cy ({e})") from None
    return np.array([[fx * scale, 0.0, (cx + 0.5) * scale - 0.5], [0.0, fy * scale, (cy + 0.5) * scale - 0.5], [0, 0, 1.0]])


def grey_frame(image: np.ndarray, index: int) -> np.ndarray:
    """Frame `index` as a grey uint8 image (from H×W×3 RGB or H×W); InputError naming the frame otherwise."""
    a = np.asarray(image)
    if a.dtype != np.uint8 or not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)):
        raise InputError(f"vo: frame {index} must be an H×W×3 (or H×W) uint8 image, got {a.dtype} {a.shape}")
    return cv2.cvtColor(a, cv2.COLOR_RGB2GRAY) if a.ndim == 3 else a


def relative_pose(
    prev_kp, prev_desc, cur_kp, cur_desc, K: np.ndarray, ransac_threshold_px: float, prob: float, seed: int
) -> tuple[int, int, np.ndarray | None, np.ndarray | None]:
    """(n_matches, n_essential_inliers, R, t) for one pair; R, t map points from the previous camera's frame into
    the current one (x_cur = R·x_prev + t, |t| = 1); None when no pose could be estimated."""
    if prev_desc is None or cur_desc is None or len(prev_kp) < 5 or len(cur_kp) < 5:
        return 0, 0, None, None
    idx_prev, idx_cur = hamming_mutual_matches(prev_desc, cur_desc)
    if len(idx_prev) < 5:
        return len(idx_prev), 0, None, None
    p1 = np.float64([prev_kp[i].pt for i in idx_prev])
    p2 = np.float64([cur_kp[i].pt for i in idx_cur])
    cv2.setRNGSeed(int(seed))  # RANSAC sampling is deterministic per pair
    E, mask = cv2.findEssentialMat(p1, p2, K, method=cv2.RANSAC, prob=prob, threshold=ransac_threshold_px)
    if E is None or mask is None or E.shape[0] < 3:
        return len(idx_prev), 0, None, None
    E = E[:3]  # several solutions come stacked (3k × 3); the mask belongs to the first
    _, R, t, _ = cv2.recoverPose(E, p1, p2, K, mask=mask.copy())
    # tracked = RANSAC inliers of E. Not recoverPose's count: it also drops points triangulated beyond 50 baselines,
    # i.e. beyond ~30 m at 30 km/h and 15 Hz, which would call a slow car on an open road "lost".
    return len(idx_prev), int(np.count_nonzero(mask)), R, t.ravel()


def track_sequence(
    images: Iterable[np.ndarray],
    K: np.ndarray,
    min_inliers: int = 20,
    gt_poses=None,
    n_features: int = 2000,
    ransac_threshold_px: float = 1.0,
    ransac_prob: float = 0.999,
    seed: int = 0,
) -> TrackingResult:
    """Track a monocular sequence (iterable of uint8 RGB frames, consumed once) with intrinsics K (3×3).
    `gt_poses`: optional sequence of 4×4 T_wc, one per frame, for scale and trajectory errors."""
    tracker = FrameToFrameTracker(K, min_inliers, gt_poses, n_features, ransac_threshold_px, ransac_prob, seed)
    for image in images:
        tracker.step(image)
    return tracker.result()


class FrameToFrameTracker:
    """`track_sequence` fed one frame at a time (`step`), for callers that produce frames in lockstep with other
    work (evaluate drives every controller of a window frame by frame); `result()` once the last frame is in."""

    def __init__(self, K: np.ndarray, min_inliers: int = 20, gt_poses=None, n_features: int = 2000,
                 ransac_threshold_px: float = 1.0, ransac_prob: float = 0.999, seed: int = 0):
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise InputError(f"vo: K must be a finite 3×3 intrinsics matrix with positive focal lengths, got {K.shape}")
        if int(min_inliers) != min_inliers or min_inliers < 5:
            raise InputError(f"vo: min_inliers must be an integer >= 5 (the five-point minimum), got {min_inliers!r}")
        gt = None if gt_poses is None else np.asarray(gt_poses, dtype=np.float64)
        if gt is not None and (gt.ndim != 3 or gt.shape[1:] != (4, 4)):
            raise InputError(f"vo: gt_poses must be a sequence of 4×4 matrices, got shape {gt.shape}")
        self.K, self.min_inliers, self.gt = K, min_inliers, gt
        self.ransac_threshold_px, self.ransac_prob, self.seed = ransac_threshold_px, ransac_prob, seed
        self._orb = cv2.ORB_create(nfeatures=int(n_features))
        self._poses = [gt[0].copy() if gt is not None else np.eye(4)]
        self._n_inl: list[int] = []
        self._n_match: list[int] = []
        self._failed_at: int | None = None
        self._prev = None
        self._shape = None
        self._i = 0

    def step(self, image: np.ndarray) -> None:
        """Add the next frame: its pair with the previous frame is matched and the pose chained."""
        i, gt = self._i, self.gt
        self._i += 1
        grey = grey_frame(image, i)
        if self._shape is None:
            self._shape = grey.shape
        elif grey.shape != self._shape:
            raise InputError(f"vo: frame {i} has size {grey.shape}, frame 0 has {self._shape}")
        kp, desc = self._orb.detectAndCompute(grey, None)
        if self._prev is not None:
            nm, ni, R, t = relative_pose(*self._prev, kp, desc, self.K, self.ransac_threshold_px, self.ransac_prob,
                                         self.seed + i)
            self._n_match.append(nm)
            self._n_inl.append(ni)
            if ni < self.min_inliers and self._failed_at is None:
                self._failed_at = i
            T_cur_prev = np.eye(4)  # lost pair: hold the pose (constant-position assumption)
            if R is not None:
                step = 1.0
                if gt is not None:
                    if i >= len(gt):
                        raise InputError(f"vo: gt_poses has {len(gt)} poses but the sequence has more frames")
                    step = float(np.linalg.norm(gt[i][:3, 3] - gt[i - 1][:3, 3]))
                T_cur_prev[:3, :3], T_cur_prev[:3, 3] = R, t * step
            self._poses.append(self._poses[-1] @ np.linalg.inv(T_cur_prev))
        self._prev = (kp, desc)

    def result(self) -> TrackingResult:
        gt, failed_at = self.gt, self._failed_at
        traj = np.array(self._poses)
        if gt is not None and len(gt) != len(traj):
            raise InputError(f"vo: gt_poses has {len(gt)} poses for {len(traj)} frames")
        ate, rpe = None, None
        n_tracked = len(traj) if failed_at is None else failed_at
        if gt is not None and n_tracked >= 2:
            ate = absolute_trajectory_error(traj[:n_tracked], gt[:n_tracked])
            rpe = relative_pose_error(traj[:n_tracked], gt[:n_tracked])
        return TrackingResult(
            success=failed_at is None,
            failed_at_frame=failed_at,
            n_inliers=np.array(self._n_inl, dtype=int),
            trajectory=traj,
            ate_m=ate,
            rpe=rpe,
            n_matches=np.array(self._n_match, dtype=int),
        )


def umeyama_rigid(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation R and translation t minimising Σ|R·src + t − dst|² (Umeyama 1991, no scale). N×3 inputs."""
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    cov = (dst - mu_d).T @ (src - mu_s) / len(src)
    U, _, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    return R, mu_d - R @ mu_s


def absolute_trajectory_error(est: np.ndarray, gt: np.ndarray) -> float:
    """RMSE (m) of camera positions after rigid alignment of `est` onto `gt` (both (N, 4, 4) T_wc)."""
    p_est, p_gt = est[:, :3, 3], gt[:, :3, 3]
    R, t = umeyama_rigid(p_est, p_gt)
    return float(np.sqrt(np.mean(np.sum((p_est @ R.T + t - p_gt) ** 2, axis=1))))


def relative_pose_error(est: np.ndarray, gt: np.ndarray) -> dict:
    """RMSE over consecutive pairs of the relative-pose error E = (gt_i⁻¹ gt_j)⁻¹ (est_i⁻¹ est_j):
    translation norm (m) and rotation angle (degrees)."""
    trans, rot = [], []
    for i in range(len(est) - 1):
        d_gt = np.linalg.inv(gt[i]) @ gt[i + 1]
        d_est = np.linalg.inv(est[i]) @ est[i + 1]
        err = np.linalg.inv(d_gt) @ d_est
        trans.append(np.linalg.norm(err[:3, 3]))
        cos = np.clip((np.trace(err[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
        rot.append(np.degrees(np.arccos(cos)))
    return {"trans_m": float(np.sqrt(np.mean(np.square(trans)))), "rot_deg": float(np.sqrt(np.mean(np.square(rot))))}
