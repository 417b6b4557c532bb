"""The benchmark's leaderboard: one row per (route split, controller) from evaluate's outputs, as a table and as JSON.

A row holds what a reader compares controllers on (docs/benchmark.md, Reading the leaderboard):
- per front end (raw grey images: `orb`, `viso`, …): the median NFM over static sections, and the median and the
  minimum NFM over dynamic sections (the tunnel entries and exits), each the mean over the split's sections as
  metrics.json has them (`expoctl.evaluation.aggregate`);
- VO: windows tracked frame to frame / windows, and against the local map (ORB-SLAM2's thresholds);
- the controller's own decision time per frame (median over its runs, ms).
Rows are ordered within a split by the first front end's dynamic minimum NFM, best first: the quantity the paper's
claim is about (consecutive frames that still match where the light changes). Reference rows (the greedy oracle,
the offline optimum) are marked and listed with the others; they are not causal controllers.
"""

from __future__ import annotations

import math
import statistics
from typing import Any, Sequence

#: controllers that are references, not causal controllers: they see the scene (`needs=("scene",)`)
REFERENCE_MARK = "*"
#: the leaderboard's name of the offline optimum's rows (not a controller: a bound over a stated grid)
OFFLINE_OPTIMUM = "offline_optimum"


def leaderboard_rows(metrics: dict, runs, frontends: Sequence[str], labels: dict[str, str] | None = None,
                     references: Sequence[str] = ()) -> list[dict[str, Any]]:
    """Rows for every (split, controller) of `metrics` (evaluate's metrics.json object) with `runs` (its runs table,
    pandas), in split order and, within a split, best dynamic minimum first (ties: by name)."""
    labels = labels or {}
    rows = []
    for split, ctrls in metrics.items():
        split_rows = []
        for name, e in ctrls.items():
            r = runs[(runs["route_split"] == split) & (runs["controller"] == name)]
            ms = r["controller_ms_median"].to_numpy(dtype=float) if len(r) else []
            ms = [m for m in ms if math.isfinite(m)]
            row = {
                "split": split, "controller": name, "label": labels.get(name, name),
                "reference": name in references,
                "nfm": {fe: {"static_median": e["static"][fe]["median_nfm"],
                             "dynamic_median": e["dynamic"][fe]["median_nfm"],
                             "dynamic_min": e["dynamic"][fe]["min_nfm"]} for fe in frontends},
                "vo_tracked": [int(e["tracking_success"][0]), int(e["tracking_success"][1])],
                "vo_map_tracked": ([int(r["vo_map_success"].astype(bool).sum()), int(len(r))]
                                   if "vo_map_success" in r.columns else None),
                "controller_ms": float(statistics.median(ms)) if ms else None,
            }
            split_rows.append(row)
        first = frontends[0]
        split_rows.sort(key=lambda row: (-_value(row["nfm"][first]["dynamic_min"]), row["controller"]))
        rows += split_rows
    return rows


def bound_rows(bound: dict, frontends: Sequence[str]) -> list[dict[str, Any]]:
    """One reference row per split for the offline optimum (`expoctl.evaluation.offline_bound.evaluate_bounds`): per front
    end the mean over sections of each section's best attainable median and minimum on the grid; no VO, no time."""
    label = f"Offline optimum ({bound['grid']['label']})"
    rows = []
    for split, kinds in bound["metrics"].items():
        cell = lambda kind, fe, stat: kinds.get(kind, {}).get(fe, {}).get(stat)  # noqa: E731
        rows.append({"split": split, "controller": OFFLINE_OPTIMUM, "label": label, "reference": True,
                     "nfm": {fe: {"static_median": cell("static", fe, "median_nfm"),
                                  "dynamic_median": cell("dynamic", fe, "median_nfm"),
                                  "dynamic_min": cell("dynamic", fe, "min_nfm")} for fe in frontends},
                     "vo_tracked": None, "vo_map_tracked": None, "controller_ms": None})
    return rows


def with_bound(rows: Sequence[dict], bound: dict | None, frontends: Sequence[str]) -> list[dict[str, Any]]:
    """`rows` with the offline optimum's row heading each split (it bounds every grid-restricted row below it)."""
    if bound is None:
        return list(rows)
    extra = {r["split"]: r for r in bound_rows(bound, frontends)}
    out: list[dict] = []
    for split in dict.fromkeys(r["split"] for r in rows):
        if split in extra:
            out.append(extra[split])
        out += [r for r in rows if r["split"] == split]
    return out


def _value(v) -> float:
    return -math.inf if v is None else float(v)


def format_leaderboard(rows: Sequence[dict], frontends: Sequence[str], frontend_labels: dict[str, str] | None = None,
                       width: int = 120) -> str:
    """The rows as a plain-text table, one block per split, at most `width` columns (front ends beyond what fits
    are left out of the text; the JSON has them all)."""
    frontend_labels = frontend_labels or {}
    name_w = max([len(_name(r)) for r in rows] + [10])
    fixed = name_w + 2 + 3 * 8  # name, VO, VO map, ms
    per_fe = 3 * 8 + 2
    shown = list(frontends[: max(1, (width - fixed) // per_fe)])
    lines: list[str] = []
    for split in dict.fromkeys(r["split"] for r in rows):
        head1 = f"{split:<{name_w}}  " + "".join(f"{frontend_labels.get(fe, fe)[:per_fe - 2]:^{per_fe - 2}}  "
                                                for fe in shown) + f"{'VO':>8}{'VO map':>8}{'ms':>8}"
        head2 = f"{'':<{name_w}}  " + "".join(f"{'static':>8}{'dynamic':>8}{'dyn min':>8}  " for _ in shown) \
            + f"{'tracked':>8}{'tracked':>8}{'/frame':>8}"
        lines += [head1.rstrip(), head2.rstrip(), "-" * min(width, len(head2))]
        for r in (r for r in rows if r["split"] == split):
            cells = "".join(f"{_num(r['nfm'][fe]['static_median'])}{_num(r['nfm'][fe]['dynamic_median'])}"
                            f"{_num(r['nfm'][fe]['dynamic_min'])}  " for fe in shown)
            vo = "{}/{}".format(*r["vo_tracked"]) if r["vo_tracked"] else "—"
            vo_map = "{}/{}".format(*r["vo_map_tracked"]) if r["vo_map_tracked"] else "—"
            ms = "—" if r["controller_ms"] is None else f"{r['controller_ms']:.2f}"
            lines.append(f"{_name(r):<{name_w}}  {cells}{vo:>8}{vo_map:>8}{ms:>8}".rstrip())
        lines.append("")
    lines.append(f"NFM: inlier matches between consecutive frames, mean over sections (median / minimum within each); "
                 f"{REFERENCE_MARK} a reference that sees the scene, not a causal controller.")
    if any(r["controller"] == OFFLINE_OPTIMUM for r in rows):
        lines.append("The offline optimum bounds every controller restricted to its grid (commands snapped to the "
                     "nearest candidate); settings off the grid can score more.")
    return "\n".join(_wrap(line, width) for line in lines)


def _name(row: dict) -> str:
    return row["label"] + (f" {REFERENCE_MARK}" if row["reference"] else "")


def _num(v) -> str:
    return f"{'—':>8}" if v is None else f"{float(v):>8.1f}"


def _wrap(line: str, width: int) -> str:
    if len(line) <= width:
        return line
    out, cur = [], ""
    for word in line.split(" "):
        if cur and len(cur) + 1 + len(word) > width:
            out.append(cur)
            cur = word
        else:
            cur = f"{cur} {word}" if cur else word
    return "\n".join(out + [cur])
