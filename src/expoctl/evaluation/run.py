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
from typing import Any, Iterator, Sequence

import cv2
import numpy as np

from expoctl.camera.response import DARK_DN, SATURATED_DN  # grey levels counted as black / clipped (8-bit)
from expoctl.controllers.base import Controller, Settings, TimedController
from expoctl.features.sumlog import SumLogParams, sumlog_uint8
from expoctl.sim.closed_loop import RigFrame, run_closed_loop
from expoctl.vo.local_map import MapTracker, MapTrackerConfig

#: front-end keys of metrics.json / frames.parquet: raw and SumLog variants of each front end


def variants(frontends) -> tuple[str, ...]:
    """The NFM columns evaluate records for these front ends: each on the raw grey image, then each on its SumLog
    transform (`orb`, `viso`, `orb_sumlog`, `viso_sumlog`): metrics.json's per-front-end keys, in this order."""
    frontends = tuple(frontends)
    return frontends + tuple(f"{f}_sumlog" for f in frontends)


def frame_variants(frames) -> tuple[str, ...]:
    """The variants a per-frame table holds (its nfm_<variant> columns), in `variants` order."""
    names = [c[len("nfm_"):] for c in frames.columns if c.startswith("nfm_")]
    return variants(n for n in names if not n.endswith("_sumlog"))


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


class PairMatches:
    """Each frame's features and inlier matches (NFM) with the frame before it, per front end, on the grey image and
    (with `sumlog`) on its SumLog transform: the one copy of evaluate's rule (`WindowRun.record`), which the benchmark
    environment's reward uses too (expoctl.bench.env). A pair's RANSAC seed is `pair_seed(sequence, k, variant)`."""

    def __init__(self, frontends: dict[str, Any], sequence: str, sumlog: dict[str, SumLogParams] | None = None):
        self.frontends, self.sequence, self.sumlog = frontends, sequence, sumlog
        self._prev: dict[str, Any] = {}

    def record(self, k: int, img: np.ndarray, grey: np.ndarray, row: dict[str, Any]) -> None:
        """Add nfeat_<variant>, nmatch_<variant> and nfm_<variant> of frame `k` (H×W×3 `img`, its `grey`) to `row`,
        in `variants` order per front end; NaN matches for the first frame recorded (no predecessor)."""
        for name, fe in self.frontends.items():
            images = [(name, grey)]
            if self.sumlog is not None:
                images.append((f"{name}_sumlog", sumlog_uint8(img, self.sumlog[name])))
            for variant, g in images:
                ext = fe.extract(g)
                row[f"nfeat_{variant}"] = int(fe.n_features(ext))
                if variant in self._prev:
                    n_m, n_i = fe.match(self._prev[variant], ext, pair_seed(self.sequence, k, variant))
                    row[f"nmatch_{variant}"], row[f"nfm_{variant}"] = float(n_m), float(n_i)
                else:  # the window's first frame has no predecessor in the window
                    row[f"nmatch_{variant}"], row[f"nfm_{variant}"] = np.nan, np.nan
                self._prev[variant] = ext


class WindowRun:
    """One controller's run over one window, fed frame by frame: `loop` is its closed loop (warm-up frames included,
    so several runs can share the window's renders in lockstep, `drive_lockstep`), `record` takes each frame the
    loop yields and `finish` returns (per-frame rows, run summary, thumbnails).

    The loop runs over [start − warm-up, stop) without a separate warm-up phase: with one camera that is the same
    sequence of captures and controller updates as `run_closed_loop(..., warmup_frames=...)` (capture t with the
    settings for t, then update), and only frames from `window.frames.start` on are recorded."""

    def __init__(
        self,
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
    ):
        from expoctl.vo.frame_to_frame import FrameToFrameTracker

        self.window, self.seed, self.frontends, self.sumlog = window, int(seed), frontends, sumlog
        self.initial = initial
        self.first_frame = max(0, window.frames.start - max(0, int(warmup_frames)))
        self.thumb_width, self.thumb_every, self.thumb_span_s = thumb_width, thumb_every, thumb_span_s
        self.timed = TimedController(controller)
        self.rows: list[dict] = []
        self.matches = PairMatches(frontends, window.sequence, sumlog)
        self._thumbs: list[np.ndarray] = []
        self._thumb_frames: list[int] = []
        self.seconds = 0.0  # time spent in this run's loop and records (lockstep: shared renders go to the first run)
        n = len(window.frames)
        gt = None if window.gt_poses is None else np.asarray(window.gt_poses)[:n]
        # the stricter, ORB-SLAM2-like test tracks the same frames against a local map (expoctl.vo.local_map)
        self.map_cfg = vo_map or MapTrackerConfig(n_features=vo_n_features)
        self.map_tracker = MapTracker(K, self.map_cfg, gt, seed=pair_seed(window.sequence, 0, "vo_map"))
        self.tracker = FrameToFrameTracker(K, vo_min_inliers, gt, vo_n_features, vo_ransac_threshold_px,
                                           seed=pair_seed(window.sequence, 0, "vo"))

    def loop(self, scene, sensor) -> Iterator[RigFrame]:
        """The closed loop over [first_frame, window stop), one `RigFrame` per frame, warm-up frames included."""
        frames = range(self.first_frame, self.window.frames.stop)
        return run_closed_loop(scene, [sensor], self.timed, self.initial, frames, self.seed)

    def record(self, rig_frame: RigFrame) -> None:
        """Statistics, features, matches and VO for one frame of the loop (warm-up frames are skipped)."""
        from expoctl.features.pipeline import rgb_to_grey

        window = self.window
        k = rig_frame.frame_index - window.frames.start
        if k < 0:
            return
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
        self.matches.record(k, img, grey, row)
        if self.thumb_width and k % self.thumb_every == 0 and abs(row["portal_dt_s"]) <= self.thumb_span_s:
            h = max(1, int(round(img.shape[0] * self.thumb_width / img.shape[1])))
            self._thumbs.append(cv2.resize(img, (self.thumb_width, h), interpolation=cv2.INTER_AREA))
            self._thumb_frames.append(k)
        self.rows.append(row)
        self.map_tracker.step(img)
        self.tracker.step(img)

    def finish(self) -> tuple[list[dict], dict, dict[str, np.ndarray]]:
        """(per-frame rows, run summary, thumbnails) once the loop has ended."""
        rows, n, timed, map_cfg = self.rows, len(self.window.frames), self.timed, self.map_cfg
        result = self.tracker.result()
        # update_ms covers warm-up frames too; the recorded frames are the last n
        ms = timed.update_ms[-n:] if timed.update_ms else []
        map_result = self.map_tracker.result()
        for k, row in enumerate(rows):
            row["vo_n_inliers"] = float(result.n_inliers[k - 1]) if k >= 1 else np.nan
            row["vo_map_n_inliers"] = float(map_result.n_inliers[k - 1]) if k >= 1 else np.nan
            row["controller_ms"] = float(ms[k]) if k < len(ms) else np.nan
        summary = {
            "sequence": self.window.sequence,
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
            "seconds": self.seconds,
            "seconds_per_frame": self.seconds / max(n, 1),
        }
        tb = {"frame": np.array(self._thumb_frames, dtype=np.int32),
              "image": np.stack(self._thumbs) if self._thumbs else np.zeros((0, 1, 1, 3), np.uint8)}
        return rows, summary, tb


def drive_lockstep(scene, sensor, runs: Sequence[WindowRun]) -> list[tuple[list[dict], dict, dict[str, np.ndarray]]]:
    """Drive several runs of one window frame by frame in step, so that a scene and sensor that remember the current
    frames (`expoctl.sim.oracle.CachedScene`, a shared sharp render, reused noise) serve frame t to every run before
    any run moves on. A run with a shorter warm-up joins at its own first frame. Each run's results are those of
    driving it alone: every frame depends only on its own settings, pose and (seed, frame) noise."""
    loops = [run.loop(scene, sensor) for run in runs]
    first = min(run.first_frame for run in runs)
    for t in range(first, runs[0].window.frames.stop):
        for run, loop in zip(runs, loops):
            if run.first_frame <= t:
                t0 = time.perf_counter()
                run.record(next(loop))
                run.seconds += time.perf_counter() - t0
    for run, loop in zip(runs, loops):  # each controller's update after the last frame, as a lone run makes it
        t0 = time.perf_counter()
        for _ in loop:
            raise RuntimeError("closed loop yielded past the window's last frame")
        run.seconds += time.perf_counter() - t0
    return [run.finish() for run in runs]


def drive_window(scene, sensor, controller: Controller, window: WindowFrames, **kwargs
                 ) -> tuple[list[dict], dict, dict[str, np.ndarray]]:
    """One controller alone over `window.frames` (keyword arguments: `WindowRun`'s); returns (per-frame rows, run
    summary, thumbnails).

    `frontends` maps "orb"/"viso" to front-end objects; `sumlog` maps the same names to their tuned SumLog params.
    Thumbnails: every `thumb_every`-th frame within `thumb_span_s` of a portal crossing, `thumb_width` px wide
    ({"frame": (k,), "image": (k, h, w, 3)}; empty when thumb_width is 0)."""
    return drive_lockstep(scene, sensor, [WindowRun(controller, window, **kwargs)])[0]
