"""Self-supervised training targets (paper §III-C): M_feat, M_match and M_hybrid over a future window.

For a time step t of one sequence the window is the frames t+L … t+L+W−1 (W = `window`, paper: 4, both cameras;
L = `latency_frames`, the first frame a command computed from frame t can expose: 1 on the paper's rig, so the
window is t+1 … t+W; 2 for a camera whose settings land at t+2).

- M_feat: of the 2·W images (t+a, camera i), a = L … L+W−1, the one with the most detected features; the target is the
  gain/exposure that image was taken with.
- M_match: of the 4·W consecutive pairs (t+b, camera i) → (t+b+1, camera j), b = L−1 … L+W−2, i, j ∈ {1, 2}
  (cross-camera pairs included), the one with the most inlier matches; the target is the settings of the *later*
  image (t+b+1, j).
- M_hybrid: weighted average of the two targets' settings (`hybrid_feat_weight` on M_feat, the rest on M_match).

"Most" is counted by one front end (`frontend: orb | viso`) or by both (`orb+viso`): each candidate's ORB and
libviso2-style counts, each divided by the best candidate's count of that front end in the same window, summed.

Tie-breaking (deterministic, by candidate order; the first maximum wins):
  1. the earliest frame in the window (smaller a, or smaller b): it is the nearest pose to t+L, where the settings
     computed at t take effect, so it approximates "the same pose" best;
  2. the reference camera (camera 1) before the perturbed camera: the paper keeps the reference settings unless a
     perturbation is *better*, and a tie is not better;
  3. for M_match, after the target camera j, the source camera i = 1 before i = 2 (it does not change the target).
  A frequent tie in practice is all-zero counts (e.g. a black frame in a tunnel): the target is then the reference
  camera's settings at t+L.

A time step gets no label when its window is incomplete: it is too close to the sequence end, or a frame id inside
t … t+L+W−1 is absent (a gap). Inconsistent input (a frame with one camera, a missing camera pairing, NaN or negative
counts, settings outside the camera range) is an `InputError` naming the table, sequence and frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import pandas as pd

from expoctl.camera import ranges
from expoctl.config_reader import Problems, Section
from expoctl.controllers.base import read_latency_frames
from expoctl.errors import InputError
from expoctl.features.registry import frontend_names

METRICS = ("feat", "match", "hybrid")
COMBINED_FRONTEND = "orb+viso"  # both front ends' counts, each relative to its best candidate (see _relative_sum)
EXPOSURE_AVERAGES = ("linear", "log")
CAMERAS = (1, 2)

FRAME_COLUMNS = ("sequence", "frame_id", "camera", "gain_db", "exposure_us")
FEATURE_COLUMNS = ("sequence", "frame_id", "camera", "frontend", "n_features")
MATCH_COLUMNS = ("sequence", "frame_id", "cam_from", "cam_to", "frontend", "n_inliers")
LABEL_COLUMNS = (
    "sequence", "frame_id", "metric", "gain_db", "exposure_us", "gain_norm", "exposure_norm",
    "target_frame_id", "target_camera", "source_camera", "score", "n_tied",
)


@dataclass(frozen=True)
class LabelConfig:
    # whose counts define "most features" / "most inlier matches": a registered front end (orb, viso, a plugin's), or
    # several joined by "+" (orb+viso): their counts, each relative to its best candidate, summed
    frontend: str = "orb"
    window: int = 4  # future frames t+L … t+L+window−1 (paper: 4, one full quadrant cycle of the perturbation)
    hybrid_feat_weight: float = 0.5  # M_hybrid = w·M_feat + (1 − w)·M_match (paper default: equal weights)
    # How M_hybrid averages exposure. "linear" (default) follows the paper ("the weighted average of the parameter
    # values") and equals averaging the network's linearly scaled targets, so the hybrid target is exactly the
    # weighted mean of the two scaled targets the L1 loss sees. "log" averages in stops (geometric mean), which is
    # photometrically even-handed: the linear mean of 1 ms and 4 ms (2.5 ms) is 1.32 EV above the first but only
    # 0.68 EV below the second. Gain is in dB, already logarithmic, so it is averaged as is either way.
    hybrid_exposure_average: str = "linear"
    # The first future frame the command computed from frame t lands on (the controller's actuation latency): the
    # window starts there, because frames before it are already committed to earlier commands. 1 = the paper's rig.
    latency_frames: int = 1

    @property
    def frontends(self) -> tuple[str, ...]:
        """The front ends whose counts the labels use."""
        return tuple(self.frontend.split("+"))

    @classmethod
    def from_dict(cls, d: Mapping | None, key: str = "labels", problems: Problems | None = None) -> "LabelConfig":
        r = Section(d, key, problems)
        frontend = r.text("frontend", cls.frontend)
        known = frontend_names()
        parts = frontend.split("+")
        if len(set(parts)) != len(parts) or not all(p in known for p in parts):
            r.problem("frontend", f"must be a front end ({', '.join(known)}) or several joined by '+' "
                                  f"(e.g. {COMBINED_FRONTEND}), got {frontend!r}")
            frontend = cls.frontend
        cfg = cls(
            frontend=frontend,
            window=r.integer("window", cls.window, min=1),
            hybrid_feat_weight=r.number("hybrid_feat_weight", cls.hybrid_feat_weight, min=0.0, max=1.0),
            hybrid_exposure_average=r.choice("hybrid_exposure_average", EXPOSURE_AVERAGES,
                                             cls.hybrid_exposure_average),
            latency_frames=read_latency_frames(r),
        )
        r.done()
        return cfg


@dataclass(frozen=True)
class FrameIndex:
    """Frames sorted by (sequence, frame_id); row r holds both cameras (column 0 = camera 1)."""

    sequence: np.ndarray  # (n,) sequence names
    seq_code: np.ndarray  # (n,) int codes of `sequence`, for fast comparisons
    frame_id: np.ndarray  # (n,) int64
    gain_db: np.ndarray  # (n, 2)
    exposure_us: np.ndarray  # (n, 2)
    section: np.ndarray | None  # (n,) from camera 1's row, if the table has it

    def __len__(self) -> int:
        return len(self.frame_id)

    def has_ahead(self, k: int) -> np.ndarray:
        """Rows r whose frame id + k exists in the same sequence (ids are unique and sorted, so all between do too)."""
        return self._has_offset(k)

    def has_behind(self, k: int) -> np.ndarray:
        """Rows r whose frame id − k exists in the same sequence (and so every frame between)."""
        return self._has_offset(-k)

    def _has_offset(self, k: int) -> np.ndarray:
        n, m = len(self), abs(k)
        ok = np.zeros(n, dtype=bool)
        if m >= n:
            return ok
        here, there = (slice(0, n - m), slice(m, n)) if k >= 0 else (slice(m, n), slice(0, n - m))
        ok[here] = (self.seq_code[there] == self.seq_code[here]) & (self.frame_id[there] == self.frame_id[here] + k)
        return ok

    def keys(self) -> pd.DataFrame:
        return pd.DataFrame({"sequence": self.sequence, "frame_id": self.frame_id, "row": np.arange(len(self))})


def row_error(name: str, rows: pd.DataFrame, what: str, cols=("sequence", "frame_id")) -> InputError:
    """An InputError naming the first offending row (and how many more there are)."""
    first = rows.iloc[0]
    label = {"frame_id": "frame"}
    place = ", ".join(f"{label.get(c, c)} '{first[c]}'" if c == "sequence" else f"{label.get(c, c)} {first[c]}"
                      for c in cols)
    more = f" (and {len(rows) - 1} more)" if len(rows) > 1 else ""
    return InputError(f"{name}: {place}: {what}{more}")


def require_columns(df: pd.DataFrame, columns, name: str) -> None:
    """InputError naming the table `name` if any of `columns` is missing."""
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise InputError(f"{name}: missing column(s) {', '.join(missing)} (has: {', '.join(map(str, df.columns))})")


def _as_int(df: pd.DataFrame, col: str, name: str, cols) -> np.ndarray:
    v = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
    bad = ~np.isfinite(v) | (v != np.round(v))
    if bad.any():
        raise row_error(name, df[bad], f"{col} is not an integer ({df[col][bad].iloc[0]})", cols)
    return v.astype(np.int64)


def _as_count(df: pd.DataFrame, col: str, name: str, cols) -> np.ndarray:
    v = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
    bad = ~np.isfinite(v) | (v < 0)
    if bad.any():
        raise row_error(name, df[bad], f"{col} is NaN or negative ({df[col][bad].iloc[0]})", cols)
    return v


def index_frames(frames: pd.DataFrame, name: str = "frames") -> FrameIndex:
    """Validate the frames table and pivot it to one row per (sequence, frame_id) with both cameras."""
    require_columns(frames, FRAME_COLUMNS, name)
    cols = ("sequence", "frame_id", "camera")
    df = frames.copy()
    df["sequence"] = df["sequence"].astype(str)
    df["frame_id"] = _as_int(df, "frame_id", name, ("sequence",))
    df["camera"] = _as_int(df, "camera", name, ("sequence", "frame_id"))
    bad = ~df["camera"].isin(CAMERAS)
    if bad.any():
        raise row_error(name, df[bad], f"camera must be 1 or 2, got {df['camera'][bad].iloc[0]}")
    for col, lo, hi in (("gain_db", ranges.GAIN_DB_MIN, ranges.GAIN_DB_MAX),
                        ("exposure_us", ranges.SENSOR_EXPOSURE_US_MIN, ranges.EXPOSURE_US_MAX)):
        v = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
        tol = 1e-6 * (hi - lo)
        bad = ~np.isfinite(v) | (v < lo - tol) | (v > hi + tol)
        if bad.any():
            raise row_error(name, df[bad], f"{col} is NaN or outside the camera range [{lo:g}, {hi:g}] "
                            f"({df[col][bad].iloc[0]})", cols)
        df[col] = np.clip(v, lo, hi)
    dup = df.duplicated(list(cols), keep=False)
    if dup.any():
        raise row_error(name, df[dup], "duplicate row for this camera", cols)
    n_cams = df.groupby(["sequence", "frame_id"], sort=False)["camera"].transform("size")
    lonely = df[n_cams != 2]
    if len(lonely):
        present = int(lonely["camera"].iloc[0])
        raise row_error(name, lonely, f"camera {3 - present} missing (every frame needs both cameras)")
    df = df.sort_values(["sequence", "frame_id", "camera"], kind="stable").reset_index(drop=True)
    cam1 = df.iloc[0::2]
    seq = cam1["sequence"].to_numpy()
    return FrameIndex(
        sequence=seq,
        seq_code=pd.factorize(seq)[0],
        frame_id=cam1["frame_id"].to_numpy(dtype=np.int64),
        gain_db=df["gain_db"].to_numpy(dtype=np.float64).reshape(-1, 2),
        exposure_us=df["exposure_us"].to_numpy(dtype=np.float64).reshape(-1, 2),
        section=cam1["section"].astype(str).to_numpy() if "section" in df.columns else None,
    )


def _select_frontend(df: pd.DataFrame, frontend: str, name: str) -> pd.DataFrame:
    sel = df[df["frontend"].astype(str) == frontend].copy()
    if sel.empty and len(df):
        present = ", ".join(sorted(df["frontend"].astype(str).unique()))
        raise InputError(f"{name}: no rows for front end {frontend!r} (present: {present})")
    sel["sequence"] = sel["sequence"].astype(str)
    return sel


def feature_counts(features: pd.DataFrame, idx: FrameIndex, frontend: str, name: str = "features") -> np.ndarray:
    """(n, 2) feature counts of every frame row and camera; every frame of `idx` must have both."""
    require_columns(features, FEATURE_COLUMNS, name)
    cols = ("sequence", "frame_id", "camera")
    df = _select_frontend(features, frontend, name)
    df["frame_id"] = _as_int(df, "frame_id", name, ("sequence",))
    df["camera"] = _as_int(df, "camera", name, ("sequence", "frame_id"))
    df["n"] = _as_count(df, "n_features", name, cols)
    dup = df.duplicated(list(cols), keep=False)
    if dup.any():
        raise row_error(name, df[dup], f"duplicate {frontend} feature count", cols)
    want = idx.keys().merge(pd.DataFrame({"camera": list(CAMERAS)}), how="cross")
    both = want.merge(df[list(cols) + ["n"]], on=list(cols), how="outer", indicator=True)
    missing = both[both["_merge"] == "left_only"].sort_values(list(cols))
    if len(missing):
        raise row_error(name, missing, f"no {frontend} feature count for this camera", cols)
    extra = both[both["_merge"] == "right_only"].sort_values(list(cols))
    if len(extra):
        raise row_error(name, extra, "feature count for a frame that is not in the frames table", cols)
    out = np.empty((len(idx), 2))
    out[both["row"].to_numpy(dtype=np.int64), both["camera"].to_numpy(dtype=np.int64) - 1] = both["n"].to_numpy()
    return out


def match_counts(matches: pd.DataFrame, idx: FrameIndex, frontend: str, name: str = "matches") -> np.ndarray:
    """(n, 2, 2) inlier counts [row, cam_from − 1, cam_to − 1] for (t, from) → (t+1, to); NaN where t+1 is absent."""
    require_columns(matches, MATCH_COLUMNS, name)
    cols = ("sequence", "frame_id", "cam_from", "cam_to")
    df = _select_frontend(matches, frontend, name)
    df["frame_id"] = _as_int(df, "frame_id", name, ("sequence",))
    for c in ("cam_from", "cam_to"):
        df[c] = _as_int(df, c, name, ("sequence", "frame_id"))
        bad = ~df[c].isin(CAMERAS)
        if bad.any():
            raise row_error(name, df[bad], f"{c} must be 1 or 2, got {df[c][bad].iloc[0]}")
    df["n"] = _as_count(df, "n_inliers", name, cols)
    dup = df.duplicated(list(cols), keep=False)
    if dup.any():
        raise row_error(name, df[dup], f"duplicate {frontend} match count", cols)
    df = df.merge(idx.keys(), on=["sequence", "frame_id"], how="left")
    unknown = df[df["row"].isna()].sort_values(list(cols))
    if len(unknown):
        raise row_error(name, unknown, "match count for a frame t that is not in the frames table")
    rows = df["row"].to_numpy(dtype=np.int64)
    has_next = idx.has_ahead(1)
    orphan = df[~has_next[rows]].sort_values(list(cols))
    if len(orphan):
        raise row_error(name, orphan, "match count from frame t to t+1, but frame t+1 is not in the frames table")
    out = np.full((len(idx), 2, 2), np.nan)
    out[rows, df["cam_from"].to_numpy() - 1, df["cam_to"].to_numpy() - 1] = df["n"].to_numpy()
    gap = has_next[:, None, None] & np.isnan(out)
    if gap.any():
        r, i, j = np.argwhere(gap)[0]
        n_more = int(gap.any(axis=(1, 2)).sum()) - 1
        more = f" (and {n_more} more frames)" if n_more else ""
        raise InputError(f"{name}: sequence '{idx.sequence[r]}', frame {idx.frame_id[r]}: {frontend} pairing camera "
                         f"{i + 1} → camera {j + 1} (frame {idx.frame_id[r]} → {idx.frame_id[r] + 1}) missing{more}")
    return out


def _argmax_first(values: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index of the first maximum per row (candidate order = tie-break order), the maximum, and how many tie."""
    k = np.argmax(values, axis=1)
    best = values[np.arange(len(values)), k]
    n_tied = (values == best[:, None]).sum(axis=1)
    return k, best, n_tied


def _relative_sum(per_frontend: list[np.ndarray]) -> np.ndarray:
    """Candidate scores (rows × candidates) summed over front ends, each divided by its best candidate in the row.

    Why relative: ORB's inlier counts run several times the libviso2-style ones, so a raw sum would be ORB's choice
    again. Dividing by the row's maximum gives each front end the same say in every window (a score of 2 = best for
    both). A front end with no feature or match anywhere in the window (max 0) contributes 0 to every candidate."""
    total = np.zeros_like(per_frontend[0], dtype=float)
    for v in per_frontend:
        best = v.max(axis=1, keepdims=True)
        total += np.divide(v, best, out=np.zeros_like(v, dtype=float), where=best > 0)
    return total


def compute_labels(frames: pd.DataFrame, features: pd.DataFrame, matches: pd.DataFrame,
                   cfg: LabelConfig | Mapping | None = None, names: Mapping[str, str] | None = None) -> pd.DataFrame:
    """The labels table: one row per labelled (sequence, frame_id) and metric (feat, match, hybrid)."""
    cfg = cfg if isinstance(cfg, LabelConfig) else LabelConfig.from_dict(cfg)
    names = {"frames": "frames", "features": "features", "matches": "matches", **(names or {})}
    idx = index_frames(frames, names["frames"])
    used = cfg.frontends
    n_feat = [feature_counts(features, idx, f, names["features"]) for f in used]
    n_inl = [match_counts(matches, idx, f, names["matches"]) for f in used]
    w, lat = cfg.window, cfg.latency_frames
    rows = np.flatnonzero(idx.has_ahead(lat + w - 1))  # t … t+lat+w−1 all present in the same sequence
    # one front end: its raw counts (score = count); orb+viso: the relative sum (score in [0, 2])
    combine = _relative_sum if len(used) > 1 else (lambda v: v[0])

    # M_feat: candidates ordered (a, camera) → first max = earliest frame, then camera 1.
    ahead = rows[:, None] + np.arange(lat, lat + w)
    k, f_score, f_tied = _argmax_first(combine([n[ahead].reshape(len(rows), 2 * w) for n in n_feat]))
    f_row, f_cam = rows + lat + k // 2, k % 2
    # M_match: candidates ordered (b, cam_to j, cam_from i) → earliest pair, then target camera 1, then source 1.
    pairs = rows[:, None] + np.arange(lat - 1, lat - 1 + w)
    k, m_score, m_tied = _argmax_first(
        combine([n[pairs].transpose(0, 1, 3, 2).reshape(len(rows), 4 * w) for n in n_inl]))
    m_row, m_cam, m_src = rows + lat + k // 4, (k // 2) % 2, k % 2

    g_f, e_f = idx.gain_db[f_row, f_cam], idx.exposure_us[f_row, f_cam]
    g_m, e_m = idx.gain_db[m_row, m_cam], idx.exposure_us[m_row, m_cam]
    wf = float(cfg.hybrid_feat_weight)
    g_h = wf * g_f + (1.0 - wf) * g_m
    if cfg.hybrid_exposure_average == "linear":
        e_h = wf * e_f + (1.0 - wf) * e_m
    else:
        e_h = np.exp(wf * np.log(e_f) + (1.0 - wf) * np.log(e_m))

    na = np.full(len(rows), np.nan)
    parts = []
    for metric, g, e, t_row, t_cam, s_cam, score, tied in (
        ("feat", g_f, e_f, f_row, f_cam, None, f_score, f_tied),
        ("match", g_m, e_m, m_row, m_cam, m_src, m_score, m_tied),
        ("hybrid", g_h, e_h, None, None, None, na, None),
    ):
        parts.append(pd.DataFrame({
            "sequence": idx.sequence[rows],
            "frame_id": idx.frame_id[rows],
            "metric": metric,
            "gain_db": g,
            "exposure_us": e,
            "gain_norm": np.clip(ranges.gain_to_norm(g), 0.0, 1.0),
            "exposure_norm": np.clip(ranges.exposure_to_norm(e), 0.0, 1.0),
            "target_frame_id": _nullable(None if t_row is None else idx.frame_id[t_row], len(rows)),
            "target_camera": _nullable(None if t_cam is None else t_cam + 1, len(rows)),
            "source_camera": _nullable(None if s_cam is None else s_cam + 1, len(rows)),
            "score": score,
            "n_tied": _nullable(tied, len(rows)),
            "_order": np.arange(len(rows)) * 3 + METRICS.index(metric),
        }))
    out = pd.concat(parts, ignore_index=True).sort_values("_order", kind="stable")
    return out.drop(columns="_order").reset_index(drop=True)


def _nullable(values, n: int) -> pd.arrays.IntegerArray:
    if values is None:
        return pd.array([pd.NA] * n, dtype="Int64")
    return pd.array(np.asarray(values, dtype=np.int64), dtype="Int64")
