"""One closed-loop evaluation run: one controller drives the simulated camera over one window of one traversal.

Per frame t (camera 1 only): the settings the frame was captured with, image statistics, and for each front end
(ORB, libviso2-style), on the raw grey image and on its SumLog transform, the feature count and the matches /
inlier matches (NFM) with frame t−1. The whole frame sequence also goes through monocular VO for the tracking-success
test, twice: frame to frame (`expoctl.vo.frame_to_frame`) and against a local map with ORB-SLAM2's thresholds
(`expoctl.vo.local_map`).
Every controller of a window sees the same scene, sensor (same randomised parameters and fixed-pattern noise) and
per-frame noise seeds, so their differences come from the settings alone.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from typing import Any, Sequence

import cv2
import numpy as np

from expoctl.camera.response import DARK_DN, SATURATED_DN  # grey levels counted as black / clipped (8-bit)
from expoctl.controllers.base import Controller, Settings, TimedController
from expoctl.features.sumlog import SumLogParams, sumlog_uint8
from expoctl.sim.closed_loop import run_closed_loop
from expoctl.vo.local_map import MapTracker, MapTrackerConfig

#: front-end keys of metrics.json / frames.parquet: raw and SumLog variants of each front end
VARIANTS = ("orb", "viso", "orb_sumlog", "viso_sumlog")


@dataclass(frozen=True)
class WindowFrames:
    """What the run needs to know about its window beyond the scene: frame range and per-frame annotations."""

    sequence: str
    frames: range  # trajectory frame indices, step 1
    section: Sequence[str]  # per frame of `frames`: static | dynamic
    portal_dt_s: Sequence[float]  # per frame: signed time to the nearest portal crossing (s; NaN if none)
    portal_kind: Sequence[str]  # per frame: entry | exit | "" (the nearest portal)
    gt_poses: np.ndarray | None  # (n, 4, 4) camera-1 T_wc per frame (for VO trajectory error)


def pair_seed(sequence: str, frame: int, variant: str) -> int:
    """RANSAC seed of a pair: same for every controller on the same window and frame (stable across processes)."""
    key = f"eval|{sequence}|{frame}|{variant}".encode()
    return int.from_bytes(hashlib.blake2b(key, digest_size=4).digest(), "little") & 0x7FFFFFFF


def image_stats(grey: np.ndarray) -> dict[str, float]:
    return {
        "mean_grey": float(grey.mean()),
        "saturated_frac": float(np.mean(grey >= SATURATED_DN)),
        "dark_frac": float(np.mean(grey <= DARK_DN)),
    }


def drive_window(
    scene,
    sensor,
    controller: Controller,
    window: WindowFrames,
    *,
    seed: int,
    frontends: dict[str, Any],
    sumlog: dict[str, SumLogParams],
    initial: Settings,
    warmup_frames: int,
    K: np.ndarray,
    vo_min_inliers: int = 20,
    vo_n_features: int = 2000,
    vo_ransac_threshold_px: float = 1.0,
    vo_map: MapTrackerConfig | None = None,
    thumb_width: int = 0,
    thumb_every: int = 1,
    thumb_span_s: float = 0.0,
) -> tuple[list[dict], dict, dict[str, np.ndarray]]:
    """Run the loop over `window.frames`; return (per-frame rows, run summary, thumbnails).

    `frontends` maps "orb"/"viso" to front-end objects; `sumlog` maps the same names to their tuned SumLog params.
    Thumbnails: every `thumb_every`-th frame within `thumb_span_s` of a portal crossing, `thumb_width` px wide
    ({"frame": (k,), "image": (k, h, w, 3)}; empty when thumb_width is 0)."""
    from expoctl.features.pipeline import rgb_to_grey
    from expoctl.vo.frame_to_frame import track_sequence

    timed = TimedController(controller)
    rows: list[dict] = []
    prev: dict[str, Any] = {}
    thumbs: list[np.ndarray] = []
    thumb_frames: list[int] = []
    t_start = time.perf_counter()

    n = len(window.frames)
    gt = None if window.gt_poses is None else np.asarray(window.gt_poses)[:n]
    # the stricter, ORB-SLAM2-like test tracks the same frames against a local map (expoctl.vo.local_map)
    map_cfg = vo_map or MapTrackerConfig(n_features=vo_n_features)
    map_tracker = MapTracker(K, map_cfg, gt, seed=pair_seed(window.sequence, 0, "vo_map"))

    def frames_and_stats():
        loop = run_closed_loop(scene, [sensor], timed, initial, window.frames, seed, warmup_frames=warmup_frames)
        for k, rig_frame in enumerate(loop):
            cam = rig_frame.camera(1)
            img = cam.image
            grey = rgb_to_grey(img)
            row: dict[str, Any] = {
                "sequence": window.sequence, "frame": k, "traj_frame": rig_frame.frame_index,
                "timestamp_ns": rig_frame.timestamp_ns, "section": str(window.section[k]),
                "portal_dt_s": float(window.portal_dt_s[k]), "portal_kind": str(window.portal_kind[k]),
                "gain_db": float(cam.settings.gain_db), "exposure_us": float(cam.settings.exposure_us),
                **image_stats(grey),
            }
            for name, fe in frontends.items():
                for variant, g in ((name, grey), (f"{name}_sumlog", sumlog_uint8(img, sumlog[name]))):
                    ext = fe.extract(g)
                    row[f"nfeat_{variant}"] = int(fe.n_features(ext))
                    if variant in prev:
                        n_m, n_i = fe.match(prev[variant], ext, pair_seed(window.sequence, k, variant))
                        row[f"nmatch_{variant}"], row[f"nfm_{variant}"] = float(n_m), float(n_i)
                    else:  # the window's first frame has no predecessor in the window
                        row[f"nmatch_{variant}"], row[f"nfm_{variant}"] = np.nan, np.nan
                    prev[variant] = ext
            if thumb_width and k % thumb_every == 0 and abs(row["portal_dt_s"]) <= thumb_span_s:
                h = max(1, int(round(img.shape[0] * thumb_width / img.shape[1])))
                thumbs.append(cv2.resize(img, (thumb_width, h), interpolation=cv2.INTER_AREA))
                thumb_frames.append(k)
            rows.append(row)
            map_tracker.step(img)
            yield img

    result = track_sequence(frames_and_stats(), K, min_inliers=vo_min_inliers, gt_poses=gt, n_features=vo_n_features,
                            ransac_threshold_px=vo_ransac_threshold_px, seed=pair_seed(window.sequence, 0, "vo"))
    seconds = time.perf_counter() - t_start
    # update_ms covers warm-up frames too; the recorded frames are the last n
    ms = timed.update_ms[-n:] if timed.update_ms else []
    map_result = map_tracker.result()
    for k, row in enumerate(rows):
        row["vo_n_inliers"] = float(result.n_inliers[k - 1]) if k >= 1 else np.nan
        row["vo_map_n_inliers"] = float(map_result.n_inliers[k - 1]) if k >= 1 else np.nan
        row["controller_ms"] = float(ms[k]) if k < len(ms) else np.nan
    summary = {
        "sequence": window.sequence,
        "n_frames": n,
        "vo_success": bool(result.success),
        "vo_failed_at": -1 if result.failed_at_frame is None else int(result.failed_at_frame),
        "vo_ate_m": float(result.ate_m) if result.ate_m is not None else np.nan,
        "vo_rpe_trans_m": float(result.rpe["trans_m"]) if result.rpe else np.nan,
        "vo_rpe_rot_deg": float(result.rpe["rot_deg"]) if result.rpe else np.nan,
        "vo_min_inliers": int(result.n_inliers.min()) if len(result.n_inliers) else 0,
        "vo_map_success": bool(map_result.success),
        "vo_map_failed_at": -1 if map_result.failed_at_frame is None else int(map_result.failed_at_frame),
        # bootstrap frames (the first map_cfg.bootstrap_frames) are not tracked, so not in the minimum
        "vo_map_min_inliers": (int(map_result.n_inliers[map_cfg.bootstrap_frames - 1:].min())
                               if len(map_result.n_inliers) >= map_cfg.bootstrap_frames else 0),
        "controller_ms_median": float(np.median(timed.update_ms)) if timed.update_ms else np.nan,
        "seconds": seconds,
        "seconds_per_frame": seconds / max(n, 1),
    }
    tb = {"frame": np.array(thumb_frames, dtype=np.int32),
          "image": np.stack(thumbs) if thumbs else np.zeros((0, 1, 1, 3), np.uint8)}
    return rows, summary, tb
