"""From per-frame evaluation rows to per-section statistics and `reports/metrics.json` (docs/evaluation.md).

A *section* is a maximal run of consecutive frames of one window with the same ground-truth label (static or
dynamic). The NFM of frame t is the inlier count of the pair (t−1, t) and belongs to frame t's section. Per section:
median and minimum NFM over its frames (sections with fewer than `min_section_frames` pairs are too short for a
meaningful minimum and are left out). Per (route split, controller, section kind, front end): the mean over
sections of those medians and minima (the paper: "averaged across all sequences").

metrics.json: {route_split: {controller: {static|dynamic: {orb|viso|orb_sumlog|viso_sumlog: {median_nfm, min_nfm}},
"tracking_success": [n_ok, n_runs]}}}. A value is null only when no section of that kind qualified.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from expoctl.controllers.registry import CONTROLLERS
from expoctl.evaluation.config import ROUTE_SPLITS
from expoctl.evaluation.run import frame_variants

SECTION_KINDS = ("static", "dynamic")


def add_section_ids(frames: pd.DataFrame) -> pd.DataFrame:
    """Number the sections of each run (column section_id, 0-based in frame order)."""
    frames = frames.sort_values(["run_id", "frame"]).reset_index(drop=True)
    change = (frames["section"] != frames.groupby("run_id")["section"].shift()).astype(int)
    frames["section_id"] = change.groupby(frames["run_id"]).cumsum() - 1
    return frames


def section_stats(frames: pd.DataFrame, min_section_frames: int = 1) -> pd.DataFrame:
    """One row per (run, section): split, controller, sequence, section kind, n_pairs, and per front-end variant
    median_nfm_<v>, min_nfm_<v>. Sections with fewer than `min_section_frames` valid pairs are dropped."""
    if "section_id" not in frames.columns:
        frames = add_section_ids(frames)
    keys = ["run_id", "route_split", "controller", "sequence", "section_id", "section"]
    VARIANTS = frame_variants(frames)
    out = []
    for key, g in frames.groupby(keys, sort=True):
        valid = g[f"nfm_{VARIANTS[0]}"].notna()
        n_pairs = int(valid.sum())
        if n_pairs < min_section_frames:
            continue
        row: dict[str, Any] = dict(zip(keys, key))
        row.update(n_pairs=n_pairs, first_frame=int(g["frame"].min()), last_frame=int(g["frame"].max()))
        for v in VARIANTS:
            vals = g.loc[valid, f"nfm_{v}"].to_numpy(dtype=float)
            row[f"median_nfm_{v}"] = float(np.median(vals))
            row[f"min_nfm_{v}"] = float(np.min(vals))
        out.append(row)
    cols = keys + ["n_pairs", "first_frame", "last_frame"] + [f"{s}_nfm_{v}" for v in VARIANTS for s in ("median", "min")]
    return pd.DataFrame(out, columns=cols)


def build_metrics(sections: pd.DataFrame, runs: pd.DataFrame) -> dict:
    """metrics.json content for every route split and controller present in `runs` (see module docstring)."""
    VARIANTS = section_variants(sections)
    metrics: dict[str, Any] = {}
    for split in ROUTE_SPLITS:
        split_runs = runs[runs["route_split"] == split]
        if split_runs.empty:
            continue
        metrics[split] = {}
        for ctrl in sorted(split_runs["controller"].unique(), key=controller_order):
            r = split_runs[split_runs["controller"] == ctrl]
            entry: dict[str, Any] = {}
            for kind in SECTION_KINDS:
                s = sections[(sections["route_split"] == split) & (sections["controller"] == ctrl)
                             & (sections["section"] == kind)]
                entry[kind] = {
                    v: {"median_nfm": _mean_or_none(s[f"median_nfm_{v}"]), "min_nfm": _mean_or_none(s[f"min_nfm_{v}"])}
                    for v in VARIANTS
                }
            entry["tracking_success"] = [int(r["vo_success"].sum()), int(len(r))]
            metrics[split][ctrl] = entry
    return metrics


def section_variants(sections: pd.DataFrame) -> tuple[str, ...]:
    """The front-end variants of a sections table (its min_nfm_<variant> columns), in `variants` order."""
    return frame_variants(pd.DataFrame(columns=[f"nfm_{c[len('min_nfm_'):]}" for c in sections.columns
                                                if c.startswith("min_nfm_")]))


def controller_order(name: str) -> tuple[int, str]:
    """Sort key of a controller in tables: its registry rank (a name no longer registered: last), then its name."""
    entries = {p.name: p.rank for p in CONTROLLERS.entries()}
    return (entries.get(name, 10**9), name)


def _mean_or_none(col: pd.Series) -> float | None:
    return float(col.mean()) if len(col) else None


def validate_metrics(metrics: Any, controllers=None, splits=ROUTE_SPLITS, frontends=None) -> list[str]:
    """Problems with a metrics.json object against the schema in docs/evaluation.md (empty list = valid).
    `controllers`, `frontends`: those it must hold (default: every registered one)."""
    from expoctl.evaluation.run import variants
    from expoctl.features.registry import FRONTENDS

    problems: list[str] = []
    if controllers is None:  # every one a default run drives (opt-in controllers only when asked for)
        from expoctl.controllers.registry import controller_names

        controllers = controller_names()
    VARIANTS = variants(FRONTENDS.names() if frontends is None else frontends)
    if not isinstance(metrics, dict):
        return [f"top level must be an object, got {type(metrics).__name__}"]
    for split in splits:
        if split not in metrics:
            problems.append(f"missing route split {split!r}")
            continue
        for ctrl in controllers:
            e = metrics[split].get(ctrl) if isinstance(metrics[split], dict) else None
            where = f"{split}.{ctrl}"
            if not isinstance(e, dict):
                problems.append(f"{where}: missing")
                continue
            extra = set(e) - set(SECTION_KINDS) - {"tracking_success"}
            if extra:
                problems.append(f"{where}: unexpected keys {sorted(extra)}")
            for kind in SECTION_KINDS:
                k = e.get(kind)
                if not isinstance(k, dict):
                    problems.append(f"{where}.{kind}: missing")
                    continue
                if set(k) != set(VARIANTS):
                    problems.append(f"{where}.{kind}: front ends {sorted(k)} != {sorted(VARIANTS)}")
                for v in VARIANTS:
                    m = k.get(v)
                    if not isinstance(m, dict) or set(m) != {"median_nfm", "min_nfm"}:
                        problems.append(f"{where}.{kind}.{v}: must be {{median_nfm, min_nfm}}, got {m!r}")
                        continue
                    for stat, val in m.items():
                        if val is not None and (isinstance(val, bool) or not isinstance(val, (int, float))
                                                or not math.isfinite(val) or val < 0):
                            problems.append(f"{where}.{kind}.{v}.{stat}: must be a number >= 0 or null, got {val!r}")
                    if all(isinstance(m.get(s), (int, float)) for s in ("median_nfm", "min_nfm")) \
                            and m["min_nfm"] > m["median_nfm"] + 1e-9:
                        problems.append(f"{where}.{kind}.{v}: min_nfm > median_nfm")
            ts = e.get("tracking_success")
            if not (isinstance(ts, list) and len(ts) == 2 and all(isinstance(x, int) and not isinstance(x, bool)
                                                                 for x in ts) and 0 <= ts[0] <= ts[1] and ts[1] >= 1):
                problems.append(f"{where}.tracking_success: must be [n_ok, n_runs] with 0 <= n_ok <= n_runs, n_runs >= 1;"
                                f" got {ts!r}")
    return problems
