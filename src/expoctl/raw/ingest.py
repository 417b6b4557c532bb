"""Ingest raw dual-camera sequences into the frames table and the training image store.

Two passes keep it safe and memory-bounded whatever the dataset size:
1. check every sequence's sequence.yaml and frames.csv and every PNG's header and end (cheap; no image decoding); if
   anything is wrong, decode every image too and stop with *all* problems (CSV cells, missing frames and partners,
   missing / truncated / corrupt images) in one error;
2. stream sequence by sequence: decode each PNG (a corrupt one is reported, and nothing is written), downsample it
   with area averaging, and write it straight into a memory-mapped `<sequence>.npy` in a staging directory.
Only if every sequence went through is the staging directory renamed over the image store and the frames table
written, so a failed ingest leaves the previous outputs untouched.

Image store: `images_dir/<sequence>.npy`, uint8, shape (n_frames, 2, H, W, 3) RGB, axis 1 = camera − 1; the frames
table's `image_index` is the row. Read it with `np.load(path, mmap_mode="r")`.
"""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import cv2
import numpy as np
import pandas as pd

from expoctl.config_reader import Problems, Section
from expoctl.errors import InputError
from expoctl.io import atomic_dir, write_parquet
from expoctl.raw.format import find_sequences, read_image_rgb
from expoctl.raw.validate import SequenceCheck, check_sequence

SPLITS = ("train", "validation", "test")
FRAMES_TABLE_COLUMNS = ["sequence", "frame_id", "camera", "timestamp_ns", "gain_db", "exposure_us", "image_path",
                        "split", "section", "image_index"]


@dataclass(frozen=True)
class IngestConfig:
    image_width: int = 224
    image_height: int = 224
    holdout_validation: float = 0.15
    holdout_test: float = 0.15

    @classmethod
    def from_dict(cls, d: dict, key: str = "ingest", problems: Problems | None = None) -> "IngestConfig":
        r = Section(d, key, problems)
        size = dict(min=8, max=4096, unit="pixels")
        hold = r.section("holdout_fractions")
        cfg = cls(r.integer("image_width", cls.image_width, **size), r.integer("image_height", cls.image_height, **size),
                  hold.number("validation", cls.holdout_validation, min=0.0, below=1.0),
                  hold.number("test", cls.holdout_test, min=0.0, below=1.0))
        if cfg.holdout_validation + cfg.holdout_test >= 1.0:
            hold.problem(None, "validation + test must leave some training data (< 1)")
        hold.done()
        r.done()
        return cfg


def assign_split(seq_dir: Path, raw_dir: Path, cfg: IngestConfig) -> str:
    """raw/<split>/<seq> → that split; otherwise a stable hash of the sequence name against the hold-out fractions."""
    rel = seq_dir.relative_to(raw_dir).parts
    if len(rel) >= 2 and rel[0] in SPLITS:
        return rel[0]
    u = int(hashlib.sha1(seq_dir.name.encode()).hexdigest()[:8], 16) / 0xFFFFFFFF
    if u < cfg.holdout_validation:
        return "validation"
    if u < cfg.holdout_validation + cfg.holdout_test:
        return "test"
    return "train"


def frame_sections(frame_ids: np.ndarray, meta: dict) -> np.ndarray:
    """Per frame: the kind of the section containing it, or 'unlabelled' (real recordings may lack sections)."""
    out = np.full(len(frame_ids), "unlabelled", dtype=object)
    for s in meta.get("sections") or []:
        inside = (frame_ids >= s["start_frame"]) & (frame_ids <= s["end_frame"])
        out[inside] = s["kind"]
    return out


def downsample(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """The one resize used for stored training images and at deployment (area averaging: no aliasing)."""
    if image.shape[1] == width and image.shape[0] == height:
        return image
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def _relpath(path: Path, root: Path) -> str:
    try:
        return os.path.relpath(path, root) if path.resolve().is_relative_to(root.resolve()) else str(path.resolve())
    except ValueError:
        return str(path.resolve())


def ingest(raw_dir: str | os.PathLike | list, frames_path: str | os.PathLike, images_dir: str | os.PathLike,
           cfg: IngestConfig, project_root: str | os.PathLike = ".",
           progress: Callable[[str], None] | None = None) -> pd.DataFrame:
    """Validate, pair and store all sequences under `raw_dir` (one directory or a list of them, e.g. both data
    collection iterations); returns the frames table (also written)."""
    raw_dirs = [Path(d) for d in (raw_dir if isinstance(raw_dir, (list, tuple)) else [raw_dir])]
    project_root = Path(project_root)
    root_of: dict[Path, Path] = {}
    for d in raw_dirs:
        for s in find_sequences(d):
            root_of[s] = d
    seq_dirs = sorted(root_of)
    if not seq_dirs:
        names = ", ".join(str(d) for d in raw_dirs)
        raise InputError(f"{names}: no sequences found (a sequence is a directory with sequence.yaml and frames.csv)")

    # Pass 1: metadata and CSVs of all sequences, every problem at once. A header-only image check cannot see a
    # corrupt PNG, which pass 2 would report only on the next run once the rest is fixed; so when pass 1 finds
    # anything, every image is decoded before stopping and the one error lists every problem there is.
    checks: list[SequenceCheck] = [check_sequence(s, decode_images=False) for s in seq_dirs]
    problems = _pass1_problems(checks)
    if problems:
        if progress:
            progress(f"{len(problems)} problem(s) in the raw data; decoding every image to report all of them at once")
        raise InputError(_problem_text(_pass1_problems([check_sequence(s, decode_images=True) for s in seq_dirs])))

    # Pass 2: decode, downsample and store, one sequence at a time.
    tables = []
    images_dir = Path(images_dir)
    with atomic_dir(images_dir) as staging:
        for c in checks:
            if progress:
                progress(f"{c.seq_dir.name}: {c.n_frames} frame pairs")
            tables.append(_ingest_sequence(c, root_of[c.seq_dir], staging, cfg, project_root, problems))
        if problems:
            raise InputError(_problem_text(problems))  # atomic_dir discards the staging directory
        frames = pd.concat(tables, ignore_index=True)[FRAMES_TABLE_COLUMNS]
        write_parquet(frames, frames_path)
    return frames


def _pass1_problems(checks: list[SequenceCheck]) -> list[str]:
    problems = [p for c in checks for p in c.problems]
    names: dict[str, Path] = {}
    for c in checks:
        if c.n_cameras != 2:  # `expoctl drive` output: valid, but training pairs two cameras per time step
            problems.append(f"{c.seq_dir}: a one-camera sequence (sequence.yaml cameras: 1, from expoctl drive); "
                            "training needs two cameras — record them with expoctl record")
        if c.seq_dir.name in names:
            problems.append(f"{c.seq_dir}: sequence name '{c.seq_dir.name}' also used by {names[c.seq_dir.name]}")
        names.setdefault(c.seq_dir.name, c.seq_dir)
    return problems


def _ingest_sequence(c: SequenceCheck, raw_dir: Path, staging: Path, cfg: IngestConfig, project_root: Path,
                     problems: list[str]) -> pd.DataFrame:
    f = c.frames
    frame_ids = np.sort(f["frame_id"].unique())
    index_of = {int(fid): i for i, fid in enumerate(frame_ids)}
    store = np.lib.format.open_memmap(staging / f"{c.seq_dir.name}.npy", mode="w+", dtype=np.uint8,
                                      shape=(len(frame_ids), 2, cfg.image_height, cfg.image_width, 3))
    size = None
    for r in f.itertuples(index=False):
        path = c.seq_dir / r.image
        try:
            img = read_image_rgb(path)
        except InputError as exc:
            problems.append(f"{c.seq_dir / 'frames.csv'}: line {r.line}, column 'image': {exc}")
            continue
        if size is None:
            size = img.shape
        elif img.shape != size:
            problems.append(f"{path}: size {img.shape[1]}x{img.shape[0]} differs from the sequence's "
                            f"{size[1]}x{size[0]}")
            continue
        store[index_of[int(r.frame_id)], int(r.camera) - 1] = downsample(img, cfg.image_width, cfg.image_height)
    store.flush()
    del store
    return pd.DataFrame({
        "sequence": c.seq_dir.name,
        "frame_id": f["frame_id"].to_numpy(np.int64),
        "camera": f["camera"].to_numpy(np.int64),
        "timestamp_ns": f["timestamp_ns"].to_numpy(np.int64),
        "gain_db": f["gain_db"].to_numpy(np.float64),
        "exposure_us": f["exposure_us"].to_numpy(np.float64),
        "image_path": [_relpath(c.seq_dir / p, project_root) for p in f["image"]],
        "split": assign_split(c.seq_dir, raw_dir, cfg),
        "section": frame_sections(f["frame_id"].to_numpy(), c.meta or {}),
        "image_index": [index_of[int(x)] for x in f["frame_id"]],
    })


def _problem_text(problems: list[str]) -> str:
    return f"{len(problems)} problem(s) in the raw data; nothing was written:\n" + "\n".join(problems)
