"""Validation of raw dual-camera sequences: every problem, one line each, naming file, row and column.

Used by `expoctl validate RAW_DIR` and by the `ingest` stage (which writes nothing if any problem is found).
Rows are reported as CSV line numbers (the header is line 1), so a user can jump straight to them.

One pass finds everything: a bad cell marks only its own row, so the structural checks (duplicates, camera-2
partners, timestamp order) still run on the other rows and every image is still checked. OpenCV's own warnings
about undecodable files are silenced: the problem list says it once, naming the file.

One-camera sequences: `expoctl drive` records a single camera and says so with `cameras: 1` in sequence.yaml.
Then every row must be camera 1, no camera-2 partner is expected and `rig.baseline_m` is not needed. Without the key
a sequence has two cameras (the training data); `ingest` accepts only those.
"""

from __future__ import annotations

import difflib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pandas as pd

from expoctl.camera.ranges import EXPOSURE_US_MAX, GAIN_DB_MAX, GAIN_DB_MIN, SENSOR_EXPOSURE_US_MIN
from expoctl.errors import InputError
from expoctl.raw.format import (
    FRAMES_COLUMNS,
    FRAMES_CSV,
    SECTION_KINDS,
    SEQUENCE_YAML,
    SOURCES,
    find_sequences,
    png_has_end,
    read_frames_csv,
    read_image_rgb,
    read_png_size,
    read_sequence_yaml,
)

#: numeric columns: (name, integer?, lower bound, upper bound)
_NUMERIC = [
    ("frame_id", True, 0, None),
    ("camera", True, 1, 2),
    ("timestamp_ns", True, 0, None),
    ("gain_db", False, GAIN_DB_MIN, GAIN_DB_MAX),
    ("exposure_us", False, SENSOR_EXPOSURE_US_MIN, EXPOSURE_US_MAX),  # a camera may go below the network's 75 µs
]


@dataclass
class SequenceCheck:
    """The outcome of checking one sequence. `frames` is typed and sorted when frames.csv parsed cleanly."""

    seq_dir: Path
    problems: list[str] = field(default_factory=list)
    meta: dict[str, Any] | None = None
    frames: pd.DataFrame | None = None
    image_size: tuple[int, int] | None = None  # (width, height)
    n_cameras: int = 2  # sequence.yaml `cameras` (1 for a one-camera recording from `expoctl drive`)

    @property
    def ok(self) -> bool:
        return not self.problems

    @property
    def n_frames(self) -> int:
        return 0 if self.frames is None else int(self.frames["frame_id"].nunique())


def check_sequence(seq_dir: str | os.PathLike, decode_images: bool = True) -> SequenceCheck:
    """Check one sequence directory. With `decode_images` every PNG is fully decoded (finds corrupt files)."""
    seq_dir = Path(seq_dir)
    check = SequenceCheck(seq_dir)
    check.meta, check.n_cameras = _check_meta(seq_dir, check.problems)
    frames, image_rows = _check_frames_csv(seq_dir, check.problems, check.n_cameras)
    if image_rows is not None:
        _check_images(seq_dir, image_rows, check, decode_images)
    if frames is not None:
        check.frames = frames
        if check.meta is not None:
            _check_meta_against_frames(seq_dir, check.meta, frames, check)
    return check


def validate_raw_dir(raw_dir: str | os.PathLike, decode_images: bool = True) -> list[str]:
    """All problems of all sequences under `raw_dir` (empty list = valid)."""
    try:
        seqs = find_sequences(raw_dir)
    except InputError as exc:
        return [str(exc)]
    if not seqs:
        return [f"{raw_dir}: no sequences found (a sequence is a directory with sequence.yaml and frames.csv)"]
    problems: list[str] = []
    for s in seqs:
        problems.extend(check_sequence(s, decode_images).problems)
    return problems


def summary_line(check: SequenceCheck) -> str:
    """One-line summary of a valid sequence."""
    f = check.frames
    w, h = check.image_size or (0, 0)
    span_s = (f["timestamp_ns"].max() - f["timestamp_ns"].min()) / 1e9 if f is not None and len(f) else 0.0
    meta = check.meta or {}
    sections = meta.get("sections") or []
    n_dyn = sum(1 for s in sections if isinstance(s, dict) and s.get("kind") == "dynamic")
    frames_word = "frame pairs" if check.n_cameras == 2 else "frames (one camera)"
    return (
        f"{check.seq_dir}: OK — {check.n_frames} {frames_word}, {w}x{h}, {span_s:.1f} s, source {meta.get('source', '?')}, "
        f"gain {f['gain_db'].min():.1f}–{f['gain_db'].max():.1f} dB, exposure {f['exposure_us'].min():.0f}–"
        f"{f['exposure_us'].max():.0f} µs, {len(sections)} sections ({n_dyn} dynamic)"
    )


# --- sequence.yaml -------------------------------------------------------------------------------------------------


def _check_meta(seq_dir: Path, problems: list[str]) -> tuple[dict[str, Any] | None, int]:
    """(the metadata if it has no problem, the number of cameras it declares — 2 unless it says `cameras: 1`)."""
    path = seq_dir / SEQUENCE_YAML
    try:
        meta = read_sequence_yaml(seq_dir)
    except InputError as exc:
        problems.append(str(exc))
        return None, 2
    before = len(problems)
    n_cameras = meta.get("cameras", 2)
    if n_cameras not in (1, 2) or isinstance(n_cameras, bool):
        problems.append(f"{path}: key 'cameras' must be 1 (a one-camera recording) or 2 (a dual-camera sequence, the "
                        f"default), got {n_cameras!r}")
        n_cameras = 2
    source = meta.get("source")
    if source not in SOURCES:
        problems.append(f"{path}: key 'source' must be one of {list(SOURCES)}, got {source!r}")
    rig = meta.get("rig")
    if not isinstance(rig, dict):
        problems.append(f"{path}: key 'rig' missing or not a mapping (needs baseline_m, fps, resolution, intrinsics)")
    else:
        for key in ("baseline_m", "fps") if n_cameras == 2 else ("fps",):
            v = rig.get(key)
            if not _is_number(v) or not v > 0:
                problems.append(f"{path}: key 'rig.{key}' must be a positive number, got {v!r}")
        res = rig.get("resolution")
        if not (isinstance(res, list) and len(res) == 2 and all(isinstance(x, int) and x > 0 for x in res)):
            problems.append(f"{path}: key 'rig.resolution' must be [width, height] positive integers, got {res!r}")
        intr = rig.get("intrinsics")
        if intr is not None:
            if not isinstance(intr, dict) or not all(_is_number(intr.get(k)) for k in ("fx", "fy", "cx", "cy")):
                problems.append(f"{path}: key 'rig.intrinsics' must map fx, fy, cx, cy to numbers, got {intr!r}")
            elif not (intr["fx"] > 0 and intr["fy"] > 0):
                problems.append(f"{path}: key 'rig.intrinsics' focal lengths must be positive, got {intr!r}")
    sections = meta.get("sections")
    if sections is not None:
        if not isinstance(sections, list):
            problems.append(f"{path}: key 'sections' must be a list of {{start_frame, end_frame, kind}}")
        else:
            for i, s in enumerate(sections):
                if not isinstance(s, dict):
                    problems.append(f"{path}: sections[{i}] must be a mapping, got {s!r}")
                    continue
                a, b, kind = s.get("start_frame"), s.get("end_frame"), s.get("kind")
                if not (isinstance(a, int) and isinstance(b, int) and 0 <= a <= b):
                    problems.append(f"{path}: sections[{i}] needs integers 0 <= start_frame <= end_frame, got {a!r}, {b!r}")
                if kind not in SECTION_KINDS:
                    problems.append(f"{path}: sections[{i}].kind must be one of {list(SECTION_KINDS)}, got {kind!r}")
    return (meta if len(problems) == before else None), n_cameras


def _check_meta_against_frames(seq_dir: Path, meta: dict, frames: pd.DataFrame, check: SequenceCheck) -> None:
    path = seq_dir / SEQUENCE_YAML
    res = meta["rig"]["resolution"]
    if check.image_size is not None and tuple(res) != check.image_size:
        check.problems.append(
            f"{path}: rig.resolution {res} differs from the images' size {list(check.image_size)}")
    if len(frames):
        last = int(frames["frame_id"].max())
        for i, s in enumerate(meta.get("sections") or []):
            if s["end_frame"] > last:
                check.problems.append(f"{path}: sections[{i}].end_frame {s['end_frame']} is past the last frame {last}")


# --- frames.csv ----------------------------------------------------------------------------------------------------


def _check_frames_csv(seq_dir: Path, problems: list[str], n_cameras: int = 2
                      ) -> tuple[pd.DataFrame | None, pd.DataFrame | None]:
    """(typed frames sorted by frame and camera if frames.csv has no problem, the rows whose images to check)."""
    path = seq_dir / FRAMES_CSV
    try:
        raw = read_frames_csv(seq_dir)
    except InputError as exc:
        problems.append(str(exc))
        return None, None
    before = len(problems)
    cols = list(raw.columns)
    for c in FRAMES_COLUMNS:
        if c not in cols:
            hint = difflib.get_close_matches(c, [x for x in cols if x not in FRAMES_COLUMNS], n=1, cutoff=0.6)
            extra = f" (found '{hint[0]}': misspelled?)" if hint else ""
            problems.append(f"{path}: missing column '{c}'{extra}")
    lines = np.arange(len(raw)) + 2
    image_rows = None
    if "image" in cols:  # images are checked whatever else is wrong with the table
        image_rows = pd.DataFrame({"image": raw["image"].astype(str), "line": lines})
        image_rows = image_rows[image_rows["image"].str.len() > 0]
    if len(problems) > before:
        return None, image_rows
    if len(raw) == 0:
        problems.append(f"{path}: empty sequence (no frames)")
        return None, None

    typed = pd.DataFrame({"image": raw["image"].astype(str)})
    bad_row = np.zeros(len(raw), dtype=bool)  # a row with any bad cell sits out the structural checks below
    for name, integer, lo, hi in _NUMERIC:
        if name == "camera":
            hi = n_cameras
        values = pd.to_numeric(raw[name], errors="coerce")
        bad = values.isna().to_numpy().copy()
        for row in np.flatnonzero(bad):
            problems.append(f"{path}: line {row + 2}, column '{name}': not a number ({raw[name].iat[row]!r})")
        v = values.to_numpy(dtype=np.float64)
        finite = np.isfinite(v)
        for row in np.flatnonzero(~finite & ~bad):
            problems.append(f"{path}: line {row + 2}, column '{name}': not finite ({raw[name].iat[row]!r})")
        bad |= ~finite
        if integer:
            frac = finite & (v != np.round(v))
            for row in np.flatnonzero(frac):
                problems.append(f"{path}: line {row + 2}, column '{name}': not an integer ({raw[name].iat[row]!r})")
            bad |= frac
        out = finite & (((v < lo) if lo is not None else False) | ((v > hi) if hi is not None else False))
        for row in np.flatnonzero(out):
            rng = f"{lo if lo is not None else '-inf'}–{hi if hi is not None else 'inf'}"
            why = " (sequence.yaml says cameras: 1)" if name == "camera" and n_cameras == 1 else ""
            problems.append(f"{path}: line {row + 2}, column '{name}': {raw[name].iat[row]} outside the valid range "
                            f"{rng}{why}")
        bad |= out
        bad_row |= bad
        typed[name] = np.where(bad, 0, v)
    csv_clean = len(problems) == before
    for name, integer, _, _ in _NUMERIC:
        if integer:
            typed[name] = typed[name].astype(np.int64)
    typed["line"] = lines
    typed = typed[~bad_row]

    dup = typed.duplicated(["frame_id", "camera"], keep="first")
    for _, r in typed[dup].iterrows():
        problems.append(f"{path}: line {r.line}: duplicate (frame_id {r.frame_id}, camera {r.camera})")
    typed = typed[~dup]
    if n_cameras == 2:
        # frame ids of rows that were dropped as bad still count as present: their problem is already reported
        bad_ids = set(pd.to_numeric(raw["frame_id"], errors="coerce")[bad_row].dropna().tolist())
        counts = typed.groupby("frame_id")["camera"].agg(list)
        for fid, cams in counts.items():
            if len(cams) == 1 and fid not in bad_ids:
                missing = 2 if cams[0] == 1 else 1
                line = int(typed.loc[typed.frame_id == fid, "line"].iat[0])
                problems.append(f"{path}: line {line}: frame_id {fid} has camera {cams[0]} but no camera {missing} partner")
    for cam, g in typed.sort_values("frame_id").groupby("camera"):
        ts = g["timestamp_ns"].to_numpy()
        for k in np.flatnonzero(np.diff(ts) <= 0):
            r = g.iloc[k + 1]
            problems.append(
                f"{path}: line {r.line}, column 'timestamp_ns': camera {cam} timestamp {r.timestamp_ns} does not increase "
                f"after frame_id {g.iloc[k].frame_id} ({g.iloc[k].timestamp_ns})")
    if not csv_clean or len(problems) > before:
        return None, image_rows
    return typed.sort_values(["frame_id", "camera"]).reset_index(drop=True), image_rows


def _check_images(seq_dir: Path, rows: pd.DataFrame, check: SequenceCheck, decode: bool) -> None:
    """Every listed image exists, decodes as 8-bit RGB (with `decode`) and has one size; `rows`: image, line."""
    _silence_opencv()
    path = seq_dir / FRAMES_CSV
    sizes: dict[tuple[int, int], tuple[int, str]] = {}
    for r in rows.itertuples(index=False):
        img_path = seq_dir / r.image
        where = f"{path}: line {r.line}, column 'image'"
        if not img_path.is_file():
            check.problems.append(f"{where}: image file {img_path} missing")
            continue
        try:
            if decode:
                img = read_image_rgb(img_path)
                size = (img.shape[1], img.shape[0])
            else:
                size = read_png_size(img_path)
                if size is None:
                    raise InputError(f"{img_path}: not a PNG file")
                if not png_has_end(img_path):  # truncated, or data after the end chunk: decode to tell which
                    read_image_rgb(img_path)
        except InputError as exc:
            check.problems.append(f"{where}: {exc}")
            continue
        sizes.setdefault(size, (r.line, r.image))
    if len(sizes) > 1:
        desc = ", ".join(f"{w}x{h} (first at line {line}, {name})" for (w, h), (line, name) in sizes.items())
        check.problems.append(f"{path}: image sizes differ within the sequence: {desc}")
    elif sizes:
        check.image_size = next(iter(sizes))


def _silence_opencv() -> None:
    """OpenCV prints its own WARN/ERROR lines for files it cannot decode (process-wide); our problem list already
    names each such file once, so they are switched off."""
    try:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
    except AttributeError:  # builds without the logging module
        cv2.setLogLevel(0)


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
