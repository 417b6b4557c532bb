"""Training samples (paper §III-B/C): the 2³ camera combinations of the input frames t, t−1, t−2 per labelled t.

Both cameras see (almost) the same scene at each time step, so each of the network's three input frames may come
from either camera; all eight combinations share the label of t. Targets are scaled linearly to [0, 1] with
`expoctl.camera.ranges` (one scaling throughout: docs/pipeline.md). The split comes from the frames table, which
assigns one split per sequence; a sequence seen in two splits is an error (splits are by sequence, never by frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import pandas as pd

from expoctl.camera import ranges
from expoctl.config_reader import Problems, Section
from expoctl.errors import InputError
from expoctl.labels.targets import METRICS, index_frames, require_columns, row_error

SPLITS = ("train", "validation", "test")
N_INPUT_FRAMES = 3  # t, t−1, t−2: the network's input (paper)
# Camera of frames (t, t−1, t−2) for the 8 samples of one time step, in sample order.
COMBINATIONS = np.array([(a, b, c) for a in (1, 2) for b in (1, 2) for c in (1, 2)], dtype=np.int64)
LABEL_INPUT_COLUMNS = ("sequence", "frame_id", "metric", "gain_db", "exposure_us")
SAMPLE_COLUMNS = ("sample_id", "sequence", "frame_id", "cam_t", "cam_t1", "cam_t2",
                  "target_gain_norm", "target_exposure_norm", "split", "metric")


@dataclass(frozen=True)
class SampleConfig:
    metric: str = "hybrid"  # which label metric becomes the target (the paper trains on M_hybrid)

    @classmethod
    def from_dict(cls, d: Mapping | None, key: str = "samples", problems: Problems | None = None) -> "SampleConfig":
        r = Section(d, key, problems)
        cfg = cls(r.choice("metric", METRICS, cls.metric))
        r.done()
        return cfg


def sample_id(sequence: str, frame_id: int, cam_t: int, cam_t1: int, cam_t2: int) -> str:
    """Stable id of one sample: the same inputs give the same id whatever else is in the dataset."""
    return f"{sequence}/{int(frame_id):06d}/c{cam_t}{cam_t1}{cam_t2}"


def sequence_splits(frames: pd.DataFrame, name: str = "frames") -> pd.Series:
    """The one split of each sequence (index: sequence name)."""
    require_columns(frames, ("sequence", "frame_id", "split"), name)
    df = frames[["sequence", "frame_id", "split"]].astype({"sequence": str})
    bad = ~df["split"].isin(SPLITS)
    if bad.any():
        raise row_error(name, df[bad], f"split must be one of {', '.join(SPLITS)}, got {df['split'][bad].iloc[0]!r}")
    per_seq = df.groupby("sequence", sort=True)["split"].unique()
    mixed = per_seq[per_seq.map(len) > 1]
    if len(mixed):
        raise InputError(f"{name}: sequence '{mixed.index[0]}' appears in several splits "
                         f"({', '.join(sorted(mixed.iloc[0]))}); splits must be by sequence")
    return per_seq.map(lambda v: str(v[0]))


def build_samples(frames: pd.DataFrame, labels: pd.DataFrame, cfg: SampleConfig | Mapping | None = None,
                  names: Mapping[str, str] | None = None) -> pd.DataFrame:
    """The samples table: 8 rows per labelled t that has frames t−1 and t−2, sorted by (sequence, frame_id, cams)."""
    cfg = cfg if isinstance(cfg, SampleConfig) else SampleConfig.from_dict(cfg)
    names = {"frames": "frames", "labels": "labels", **(names or {})}
    idx = index_frames(frames, names["frames"])
    splits = sequence_splits(frames, names["frames"])

    require_columns(labels, LABEL_INPUT_COLUMNS, names["labels"])
    lab = labels[labels["metric"].astype(str) == cfg.metric].copy()
    if lab.empty and len(labels):
        present = ", ".join(sorted(labels["metric"].astype(str).unique()))
        raise InputError(f"{names['labels']}: no labels for metric {cfg.metric!r} (present: {present})")
    lab["sequence"] = lab["sequence"].astype(str)
    fid = pd.to_numeric(lab["frame_id"], errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
    bad = ~np.isfinite(fid) | (fid != np.round(fid))
    if bad.any():
        raise row_error(names["labels"], lab[bad], "frame_id is not an integer", ("sequence",))
    lab["frame_id"] = fid.astype(np.int64)
    dup = lab.duplicated(["sequence", "frame_id"], keep=False)
    if dup.any():
        raise row_error(names["labels"], lab[dup], f"duplicate {cfg.metric} label")
    for col, lo, hi in (("gain_db", ranges.GAIN_DB_MIN, ranges.GAIN_DB_MAX),
                        ("exposure_us", ranges.SENSOR_EXPOSURE_US_MIN, ranges.EXPOSURE_US_MAX)):
        v = pd.to_numeric(lab[col], errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
        tol = 1e-6 * (hi - lo)
        bad = ~np.isfinite(v) | (v < lo - tol) | (v > hi + tol)
        if bad.any():
            raise row_error(names["labels"], lab[bad], f"{col} is NaN or outside [{lo:g}, {hi:g}]")
        lab[col] = v
    lab = lab.merge(idx.keys(), on=["sequence", "frame_id"], how="left")
    unknown = lab[lab["row"].isna()]
    if len(unknown):
        raise row_error(names["labels"], unknown, "label for a frame that is not in the frames table")

    # The network needs frames t−1 and t−2 (same sequence): labels at the start of a sequence or after a gap drop.
    has_history = idx.has_behind(N_INPUT_FRAMES - 1)
    lab = lab[has_history[lab["row"].to_numpy(dtype=np.int64)]].sort_values(["sequence", "frame_id"], kind="stable")

    n_combo = len(COMBINATIONS)
    rep = lambda a: np.repeat(np.asarray(a), n_combo)  # noqa: E731 — one row per combination
    cams = np.tile(COMBINATIONS, (len(lab), 1))
    seq = rep(lab["sequence"].to_numpy())
    frame = rep(lab["frame_id"].to_numpy(dtype=np.int64))
    ids = [sample_id(s, f, a, b, c) for s, f, (a, b, c) in zip(seq, frame.tolist(), cams.tolist())]
    return pd.DataFrame({
        "sample_id": np.array(ids, dtype=object),
        "sequence": seq,
        "frame_id": frame,
        "cam_t": cams[:, 0],
        "cam_t1": cams[:, 1],
        "cam_t2": cams[:, 2],
        "target_gain_norm": rep(np.clip(ranges.gain_to_norm(lab["gain_db"].to_numpy()), 0.0, 1.0)),
        "target_exposure_norm": rep(np.clip(ranges.exposure_to_norm(lab["exposure_us"].to_numpy()), 0.0, 1.0)),
        "split": splits.reindex(seq).to_numpy(dtype=object),
        "metric": cfg.metric,
    })


def summarise_samples(samples: pd.DataFrame) -> dict:
    """Counts per split (samples, labelled time steps, sequences) for logging."""
    out = {}
    for split in SPLITS:
        s = samples[samples["split"] == split]
        out[split] = {"n_samples": int(len(s)), "n_time_steps": int(len(s) // len(COMBINATIONS)),
                      "n_sequences": int(s["sequence"].nunique())}
    return out
