"""The features stage's library: feature counts per image and inlier matches per consecutive pair.

For every sequence of the frames table: every image (both cameras, every frame) is read once, converted to grey and
extracted once per front end; its feature count goes to the `features` table. For every time step t the four
pairings (camera i at t → camera j at t+1, i, j ∈ {1, 2}) are matched and go to the `matches` table (frame_id = t).
Only two time steps are held in memory at a time.

Sequences are independent, so they are spread over workers (`expoctl.parallel`: processes on this host or a Ray
cluster); results do not depend on n_jobs or the backend: every pair's RANSAC seed is a hash of (base seed, sequence,
frame, cameras, front end), never of the order of work, and the tables are sorted.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Mapping
from typing import Any, Iterable

import cv2
import numpy as np
import pandas as pd

from expoctl.config_reader import Problems, Section
from expoctl.errors import InputError
from expoctl.features.frontend import PairCounts
from expoctl.features.registry import FRONTENDS, frontend, frontend_names, make_frontend
from expoctl.features.sumlog import SumLogGrid
from expoctl.parallel import MOVED_N_JOBS, ParallelConfig, run_ordered
from expoctl.raw.format import decode_8bit_image

FRAMES_COLUMNS = ("sequence", "frame_id", "camera", "image_path")
FEATURES_COLUMNS = ["sequence", "frame_id", "camera", "frontend", "n_features"]
MATCHES_COLUMNS = ["sequence", "frame_id", "cam_from", "cam_to", "frontend", "n_matches", "n_inliers"]
CAMERAS = (1, 2)


@dataclass(frozen=True)
class FeaturesConfig:
    """The `features` config group (conf/features/default.yaml): which front ends the features stage runs, and every
    registered front end's typed config (`features.<name>`, read once here; evaluate runs its own choice of them)."""

    frontends: tuple[str, ...] = field(default_factory=frontend_names)  # null in the config: every registered one
    configs: Mapping[str, Any] = field(default_factory=dict)  # front-end name -> its typed config, every registered
    seed: int = 0
    sumlog: SumLogGrid = SumLogGrid()  # SumLog tuning grid (sumlog.tune_sumlog); not used by compute_features

    def config(self, name: str) -> Any:
        """The typed config of front end `name` (its defaults when the config read none)."""
        if name in self.configs:
            return self.configs[name]
        return frontend(name, "features.frontends").config()

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "features", problems: Problems | None = None) -> "FeaturesConfig":
        r = Section(d, key, problems)
        known = frontend_names()
        frontends = FRONTENDS.read_names(r, "frontends")  # null: every registered front end
        configs = {}
        for name in known:  # every front end's keys, checked by its own typed config
            sub = r.section(name)
            configs[name] = sub.read(frontend(name).config)
            sub.done()
        r.moved("n_jobs", "parallel.n_jobs", MOVED_N_JOBS)
        seed = r.integer("seed", 0)
        sumlog = SumLogGrid.from_dict(r.value("sumlog", None), r.path("sumlog"), r.problems)
        r.done()
        return cls(frontends, configs, seed, sumlog)


def read_grey(path: str | os.PathLike) -> np.ndarray:
    """Decode an 8-bit image file (grey, RGB or RGBA) to H×W uint8 grey; InputError naming the file otherwise.

    Colour goes through cv2.cvtColor's Rec.601 weights (the same call `rgb_to_grey` makes on in-memory frames), not
    the PNG decoder's own conversion, so a file and the array it was written from give the same grey image.
    """
    path = Path(path)
    img = decode_8bit_image(path)
    if img.ndim == 2:
        return img
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
    raise InputError(f"{path}: expected a grey or RGB image, got shape {img.shape}")


def rgb_to_grey(rgb: np.ndarray) -> np.ndarray:
    """H×W×3 uint8 RGB → H×W uint8 grey (Rec.601 weights, as read_grey)."""
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)


def match_images(frontend, prev_grey: np.ndarray, cur_grey: np.ndarray, seed: int = 0) -> PairCounts:
    """Counts for one pair of grey images (what `expoctl match` prints and closed-loop evaluation needs)."""
    if prev_grey.shape != cur_grey.shape:
        raise InputError(f"image sizes differ: {prev_grey.shape[1]}×{prev_grey.shape[0]} vs "
                         f"{cur_grey.shape[1]}×{cur_grey.shape[0]}")
    a, b = frontend.extract(prev_grey), frontend.extract(cur_grey)
    n_matches, n_inliers = frontend.match(a, b, seed)
    return PairCounts(frontend.n_features(a), frontend.n_features(b), int(n_matches), int(n_inliers))


def pair_seed(base_seed: int, sequence: str, frame_id: int, cam_from: int, cam_to: int, frontend: str) -> int:
    """A 31-bit RANSAC seed that depends only on what the pair is (stable across runs, platforms and n_jobs)."""
    key = f"{base_seed}|{sequence}|{frame_id}|{cam_from}|{cam_to}|{frontend}".encode()
    return int.from_bytes(hashlib.blake2b(key, digest_size=4).digest(), "little") & 0x7FFFFFFF


# ----------------------------------------------------------------------------------------------------------- input


@dataclass(frozen=True)
class _SequenceTask:
    sequence: str
    frame_ids: tuple[int, ...]
    paths: dict  # (frame_id, camera) -> absolute image path
    frontends: tuple[tuple[str, dict], ...]
    seed: int


def _plan(frames_df: pd.DataFrame, project_root: Path, cfg: FeaturesConfig) -> list[_SequenceTask]:
    """Check the frames table (InputError naming sequence/frame/camera) and cut it into one task per sequence."""
    missing = [c for c in FRAMES_COLUMNS if c not in frames_df.columns]
    if missing:
        raise InputError(f"frames table: missing column(s) {', '.join(missing)}")
    if frames_df.empty:
        raise InputError("frames table: no rows (nothing to compute features for)")
    df = frames_df.loc[:, list(FRAMES_COLUMNS)].copy()
    for col in FRAMES_COLUMNS:
        empty = df[col].isna()
        if empty.any():
            raise InputError(f"frames table row {df.index[empty.to_numpy()][0]}: column {col} is empty")
    for col in ("frame_id", "camera"):
        values = pd.to_numeric(df[col], errors="coerce")
        bad = values.isna() | (values != np.floor(values))
        if bad.any():
            row = df.index[bad.to_numpy()][0]
            raise InputError(f"frames table row {row}: column {col} must be an integer, got {df.at[row, col]!r}")
        df[col] = values.astype(np.int64)
    bad_cam = ~df["camera"].isin(CAMERAS)
    if bad_cam.any():
        r = df[bad_cam].iloc[0]
        raise InputError(f"frames table: sequence {r.sequence} frame {r.frame_id}: camera must be 1 or 2, got {r.camera}")
    dup = df.duplicated(["sequence", "frame_id", "camera"])
    if dup.any():
        r = df[dup].iloc[0]
        raise InputError(f"frames table: sequence {r.sequence} frame {r.frame_id} camera {r.camera} appears twice")
    fronts = tuple((name, cfg.config(name)) for name in cfg.frontends)
    tasks = []
    for sequence, seq in df.groupby("sequence", sort=True):
        seq = seq.sort_values(["frame_id", "camera"])
        frame_ids = np.unique(seq["frame_id"].to_numpy())
        have = set(zip(seq["frame_id"].tolist(), seq["camera"].tolist()))
        for f in frame_ids.tolist():
            for cam in CAMERAS:
                if (f, cam) not in have:
                    raise InputError(f"frames table: sequence {sequence} frame {f}: camera {cam} image missing "
                                     f"(every time step needs both cameras)")
        gaps = np.flatnonzero(np.diff(frame_ids) != 1)
        if gaps.size:
            f = int(frame_ids[gaps[0]])
            raise InputError(f"frames table: sequence {sequence}: frame {f + 1} missing (frames jump from {f} to "
                             f"{int(frame_ids[gaps[0] + 1])}); pairs t → t+1 need consecutive frames")
        paths = {(int(f), int(c)): str(Path(project_root) / p)
                 for f, c, p in zip(seq["frame_id"], seq["camera"], seq["image_path"])}
        tasks.append(_SequenceTask(str(sequence), tuple(int(f) for f in frame_ids), paths, fronts, cfg.seed))
    return tasks


# ---------------------------------------------------------------------------------------------------------- worker

_FRONTEND_CACHE: dict[tuple[str, str], Any] = {}


def _frontend(name: str, config: Any):
    """One front end per (name, typed config) per worker process (a config's repr names all its values)."""
    key = (name, repr(config))
    if key not in _FRONTEND_CACHE:
        _FRONTEND_CACHE[key] = make_frontend(name, config)
    return _FRONTEND_CACHE[key]


def _worker_init() -> None:
    # one OpenCV thread per worker: the pool already uses the cores, nested threads would only contend
    cv2.setNumThreads(1)


def _process_sequence(task: _SequenceTask) -> tuple[list[tuple], list[tuple]]:
    """Feature rows and match rows of one sequence; each image is read and extracted exactly once."""
    fronts = [(name, _frontend(name, params)) for name, params in task.frontends]
    feature_rows: list[tuple] = []
    match_rows: list[tuple] = []
    expected_shape = None
    reference_path = None
    previous: dict[tuple[str, int], Any] | None = None  # (front end, camera) -> extraction at t-1
    for t in task.frame_ids:
        current: dict[tuple[str, int], Any] = {}
        for cam in CAMERAS:
            path = task.paths[(t, cam)]
            grey = read_grey(path)
            if expected_shape is None:
                expected_shape, reference_path = grey.shape, path
            elif grey.shape != expected_shape:
                raise InputError(f"{path}: image is {grey.shape[1]}×{grey.shape[0]} but {reference_path} (same "
                                 f"sequence {task.sequence}) is {expected_shape[1]}×{expected_shape[0]}")
            for name, fe in fronts:
                ext = fe.extract(grey)
                current[(name, cam)] = ext
                feature_rows.append((task.sequence, t, cam, name, int(fe.n_features(ext))))
        if previous is not None:
            for name, fe in fronts:
                for cam_from in CAMERAS:
                    for cam_to in CAMERAS:
                        seed = pair_seed(task.seed, task.sequence, t - 1, cam_from, cam_to, name)
                        n_matches, n_inliers = fe.match(previous[(name, cam_from)], current[(name, cam_to)], seed)
                        match_rows.append((task.sequence, t - 1, cam_from, cam_to, name, int(n_matches), int(n_inliers)))
        previous = current
    return feature_rows, match_rows


# ------------------------------------------------------------------------------------------------------------ main


def compute_features(
    frames_df: pd.DataFrame,
    project_root: str | os.PathLike,
    params: dict | FeaturesConfig,
    n_jobs: int | None = None,
    progress: bool = True,
    parallel: ParallelConfig | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """(features_df, matches_df) for every image and every consecutive pair of the frames table.

    params: the `features` config group (dict) or a FeaturesConfig. parallel: where the sequences run and how many
    worker processes (`parallel.n_jobs`; default: this process); never changes a result. n_jobs: another worker
    count than parallel's (-1 → all cores; 1 → in this process). Bad input raises InputError naming the
    file/sequence/frame.
    """
    cfg = params if isinstance(params, FeaturesConfig) else FeaturesConfig.from_dict(params)
    for name in cfg.frontends:  # build each front end once before any work (a plugin's constructor may refuse)
        make_frontend(name, cfg.config(name))
    parallel = (parallel or ParallelConfig()).with_jobs(n_jobs)
    tasks = _plan(frames_df, Path(project_root), cfg)
    results = _run_tasks(tasks, parallel.workers, progress, parallel)
    feature_rows = [row for feats, _ in results for row in feats]
    match_rows = [row for _, matches in results for row in matches]
    features = pd.DataFrame(feature_rows, columns=FEATURES_COLUMNS)
    matches = pd.DataFrame(match_rows, columns=MATCHES_COLUMNS)
    features = features.sort_values(["sequence", "frame_id", "camera", "frontend"], kind="stable").reset_index(drop=True)
    matches = matches.sort_values(["sequence", "frame_id", "cam_from", "cam_to", "frontend"], kind="stable")
    matches = matches.reset_index(drop=True)
    for df, cols in ((features, ["frame_id", "camera", "n_features"]),
                     (matches, ["frame_id", "cam_from", "cam_to", "n_matches", "n_inliers"])):
        for col in cols:
            df[col] = df[col].astype(np.int64)
        for col in ("sequence", "frontend"):
            df[col] = df[col].astype(str)
    return features, matches


def _run_tasks(tasks: list[_SequenceTask], n_jobs: int, progress: bool,
               parallel: ParallelConfig | None = None) -> list[tuple[list, list]]:
    """Run the per-sequence tasks (results in task order), with a progress bar over images. Worker processes come
    from a fork server (spawn where the OS has none), never plain fork: forking a process whose other threads
    (OpenCV's pool, numba, tqdm's monitor) hold a lock leaves the child waiting on that lock forever (seen: workers
    stuck in futex_wait). The fork server is a fresh single-threaded process that imports this module once; workers
    fork from it, so they start in milliseconds instead of re-importing cv2/numba/pandas like spawned ones."""
    from tqdm import tqdm

    total_images = sum(len(t.paths) for t in tasks)
    with tqdm(total=total_images, unit="img", desc="features", disable=not progress) as bar:
        return [result for _, result in run_ordered(_process_sequence, tasks, n_jobs, parallel,
                                                    progress=lambda task, _r: bar.update(len(task.paths)),
                                                    initializer=_worker_init, start_method="forkserver",
                                                    preload=[__name__])]


def iter_training_pairs_rgb(frames_df: pd.DataFrame, project_root: str | os.PathLike, camera: int = 1,
                            max_pairs: int | None = None) -> Iterable[tuple[np.ndarray, np.ndarray]]:
    """Sequential (t, t+1) RGB pairs of one camera from the train split, for SumLog tuning (sumlog.tune_sumlog)."""
    from expoctl.raw.format import read_image_rgb

    df = frames_df
    if "split" in df.columns:
        df = df[df["split"] == "train"]
    df = df[df["camera"] == camera].sort_values(["sequence", "frame_id"])
    n = 0
    for _, seq in df.groupby("sequence", sort=True):
        paths = seq.set_index("frame_id")["image_path"]
        prev_img = None
        prev_f = None
        for f, p in paths.items():
            img = read_image_rgb(Path(project_root) / p)
            if prev_img is not None and f == prev_f + 1:
                yield prev_img, img
                n += 1
                if max_pairs is not None and n >= max_pairs:
                    return
            prev_img, prev_f = img, f
