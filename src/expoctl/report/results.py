"""The `report` stage's library: reports/results.md (tables shaped like the paper's Tables I–III, from our numbers,
with the oracle and the extra baselines) and reports/figures/*.png (Fig. 6 and Fig. 7 analogues), from
reports/metrics.json and reports/eval/.

Table conventions: rows are controllers; **bold** marks the best causal controller per column. The greedy oracle is
not causal (it sees the next frame before choosing) but is no bound either (one step at a time: a causal controller
can beat it), so it is shown in italics and never bolded; so is the offline optimum over a grid, when evaluate wrote
reports/eval/offline_bound.json (expoctl.evaluation.offline_bound: what no controller restricted to that grid can beat).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from expoctl.config_reader import Problems, Section
from expoctl.errors import InputError
from expoctl.io import atomic_dir
from expoctl.evaluation.aggregate import validate_metrics
from expoctl.report.figures import frontend_label, image_strips, label, nfm_bars, ordered, tunnel_timeline

SPLIT_TITLE = {"validation": "validation city (training city, other conditions)", "test": "test city (unseen)"}
#: the paper's numbers (Tables I–III) to compare shapes with; absolute values differ (real camera, 2048×1536)
PAPER_DYNAMIC = {  # validation, dynamic sections: (ORB median, libviso2 median, ORB min, libviso2 min)
    "agae": (393, 5350, 54, 301),
    "learned": (395, 7380, 98, 421),
}


@dataclass(frozen=True)
class ReportConfig:
    strip_split: str = "test"
    strip_portal: str = "exit"
    strip_columns: int = 6

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "report", problems: Problems | None = None) -> "ReportConfig":
        r = Section(d, key, problems)
        cfg = cls(r.choice("strip_split", ("validation", "test"), cls.strip_split),
                  r.choice("strip_portal", ("entry", "exit"), cls.strip_portal),
                  r.integer("strip_columns", cls.strip_columns, min=1, max=20))
        r.done()
        return cfg


def load_eval(reports_dir: str | os.PathLike) -> tuple[dict, pd.DataFrame, pd.DataFrame]:
    """metrics.json, frames.parquet and runs.parquet; InputError naming the file when missing or malformed."""
    reports_dir = Path(reports_dir)
    mpath = reports_dir / "metrics.json"
    if not mpath.is_file():
        raise InputError(f"{mpath}: missing; run the evaluate stage first")
    try:
        metrics = json.loads(mpath.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{mpath}: not valid JSON ({exc})") from None
    present = [s for s in ("validation", "test") if s in metrics] if isinstance(metrics, dict) else []
    ctrls = ordered({c for s in present for c in metrics[s]})
    fes = metrics_frontends(metrics)
    problems = (validate_metrics(metrics, ctrls, present, fes) if present and fes is not None
                else ["no route split (validation, test)" if not present else "no controller entry with front ends"])
    if problems:
        raise InputError(f"{mpath}: does not follow the metrics.json schema: " + "; ".join(problems[:5]))
    tables = []
    for name in ("frames", "runs"):
        p = reports_dir / "eval" / f"{name}.parquet"
        if not p.is_file():
            raise InputError(f"{p}: missing; run the evaluate stage first")
        try:
            tables.append(pd.read_parquet(p))
        except Exception as exc:  # pyarrow raises several types for a damaged file
            raise InputError(f"{p}: not a readable Parquet file ({exc})") from None
    return metrics, tables[0], tables[1]


def _fmt(v) -> str:
    return "—" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.0f}"


def metrics_frontends(metrics: dict) -> list[str] | None:
    """The raw front ends a metrics.json holds (those of its first entry, in order); None if it has no entry."""
    for split in ("validation", "test"):
        for entry in (metrics.get(split) or {}).values() if isinstance(metrics.get(split), dict) else ():
            kinds = entry.get("dynamic") if isinstance(entry, dict) else None
            if isinstance(kinds, dict):
                return [fe for fe in kinds if not fe.endswith("_sumlog")]
    return None


def nfm_table(metrics: dict, split: str, kinds=("static", "dynamic"), sumlog: bool = False,
              bound: dict | None = None) -> str:
    """Markdown table: Lighting | Method | Median NFM per front end (ORB, libviso2, …) | Minimum NFM per front end.
    `bound`: offline_bound.json's content, a last row per lighting (its grid and render size in the label)."""
    ctrls = ordered(metrics[split])
    raw = metrics_frontends(metrics) or []
    fes = tuple(f"{fe}_sumlog" for fe in raw) if sumlog else tuple(raw)
    heads = [f"{stat} NFM {frontend_label(fe)}" for stat in ("Median", "Minimum") for fe in raw]
    lines = ["| Lighting | Method | " + " | ".join(heads) + " |", "|---|---|" + "---:|" * len(heads)]
    for kind in kinds:
        cols = [(stat, fe) for stat in ("median_nfm", "min_nfm") for fe in fes]
        best = {}
        for stat, fe in cols:
            vals = [metrics[split][c][kind][fe][stat] for c in ctrls if c != "oracle"]
            vals = [v for v in vals if v is not None]
            best[(stat, fe)] = max(vals) if vals else None
        for i, c in enumerate(ctrls):
            cells = []
            for stat, fe in cols:
                v = metrics[split][c][kind][fe][stat]
                s = _fmt(v)
                if c == "oracle":
                    s = f"*{s}*"
                elif v is not None and best[(stat, fe)] and v == best[(stat, fe)]:  # no bold when all are 0
                    s = f"**{s}**"
                cells.append(s)
            name = label(c) + (" (SL)" if sumlog else "")
            if c == "oracle":
                name = f"*{name}, one step*"
            lines.append(f"| {'**' + kind.capitalize() + '**' if i == 0 else ''} | {name} | " + " | ".join(cells) + " |")
        row = bound_row(bound, split, kind, cols)
        if row:
            lines.append(f"| | {row[0]}{' (SL)' if sumlog else ''} | " + " | ".join(row[1]) + " |")
    return "\n".join(lines)


def bound_label(bound: dict) -> str:
    """The offline optimum's row label: its grid and the render size it was computed at."""
    w, h = bound["render_size"]
    return f"*offline optimum ({bound['grid']['label']}, {w}×{h})*"


def bound_row(bound: dict | None, split: str, kind: str, cols) -> tuple[str, list[str]] | None:
    """(label, cells) of the offline optimum for one split and lighting, or None when it has no such section; a front
    end it did not bound (the SumLog variants unless evaluate.offline_bound.sumlog) reads —."""
    per = ((bound or {}).get("metrics") or {}).get(split, {}).get(kind)
    if not per:
        return None
    return bound_label(bound), [f"*{_fmt(per[fe][stat])}*" if fe in per else "—" for stat, fe in cols]


def load_bound(reports_dir: str | os.PathLike) -> dict | None:
    """reports/eval/offline_bound.json (evaluate.offline_bound.enabled), or None when evaluate did not write it."""
    path = Path(reports_dir) / "eval" / "offline_bound.json"
    if not path.is_file():
        return None
    try:
        bound = json.loads(path.read_text())
        bound["grid"]["label"], bound["render_size"][1], bound["metrics"].items()
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as exc:
        raise InputError(f"{path}: not an offline-bound report ({exc!r})") from None
    return bound


def tracking_table(metrics: dict, runs: pd.DataFrame) -> str:
    """Table III: VO tracking successes per controller and split, frame to frame (metrics.json) and, when the runs
    carry it, against a local map with ORB-SLAM2's thresholds (expoctl.vo.local_map), plus the mean frame-to-frame ATE
    over successful runs."""
    splits = [s for s in ("validation", "test") if s in metrics]
    ctrls = ordered({c for s in splits for c in metrics[s]})
    has_map = "vo_map_success" in runs.columns
    head = "| Method | " + " | ".join(f"VO successes, {s}" for s in splits) + " | " + \
        ("".join(f"map-tracking VO successes, {s} | " for s in splits) if has_map else "") + \
        " | ".join(f"ATE (m), {s} successes" for s in splits) + " |"
    lines = [head, "|---|" + "---:|" * ((3 if has_map else 2) * len(splits))]
    for c in ctrls:
        cells = []
        for s in splits:
            e = metrics[s].get(c)
            cells.append("—" if e is None else f"{e['tracking_success'][0]}/{e['tracking_success'][1]}")
        if has_map:
            for s in splits:
                r = runs[(runs.route_split == s) & (runs.controller == c)]
                cells.append(f"{int(r.vo_map_success.astype(bool).sum())}/{len(r)}" if len(r) else "—")
        for s in splits:
            r = runs[(runs.route_split == s) & (runs.controller == c) & runs.vo_success.astype(bool)]
            ate = r["vo_ate_m"].to_numpy(dtype=float)
            ate = ate[np.isfinite(ate)]
            cells.append(f"{ate.mean():.2f}" if len(ate) else "—")
        lines.append(f"| {label(c)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


#: stricter tracking thresholds (tracked inliers per frame pair) for the VO margin table. The frame-to-frame VO here
#: is more lenient than the paper's ORB-SLAM2, which tracks map points from older keyframes.
VO_MARGIN_THRESHOLDS = (20, 50, 100, 150, 200)


def vo_margin_table(runs: pd.DataFrame, thresholds=VO_MARGIN_THRESHOLDS, column: str = "vo_min_inliers") -> str:
    """Per controller and split: each run's worst tracked count (`column`: the frame-to-frame VO's worst pair,
    `vo_min_inliers`, or the map tracker's worst scored frame, `vo_map_min_inliers`; the strictest threshold at
    which that run would still have tracked), as min / median over runs, and the runs of both splits tracked at
    stricter thresholds (a run fails below the threshold)."""
    splits = [s for s in ("validation", "test") if s in set(runs.route_split)]
    ctrls = ordered(set(runs.controller))
    head = "| Method | " + " | ".join(f"worst, {s}: min / median over runs" for s in splits) + " | " + \
        " | ".join(f"tracked at ≥ {t}" for t in thresholds) + " |"
    lines = [head, "|---|" + "---:|" * (len(splits) + len(thresholds))]
    for c in ctrls:
        cells = []
        for s in splits:
            w = runs.loc[(runs.route_split == s) & (runs.controller == c), column].to_numpy(float)
            cells.append(f"{w.min():.0f} / {np.median(w):.0f}" if len(w) else "—")
        w_all = runs.loc[runs.controller == c, column].to_numpy(float)
        cells += [f"{int((w_all >= t).sum())}/{len(w_all)}" for t in thresholds]
        lines.append(f"| {label(c)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def runs_table(runs: pd.DataFrame) -> str:
    """Per window and controller: the frame where VO lost track ("tracked" = throughout), frame to frame and, when
    the runs carry it, against the local map (after the slash)."""
    ctrls = ordered(set(runs.controller))
    lines = ["| Window | " + " | ".join(label(c) for c in ctrls) + " |", "|---|" + "---:|" * len(ctrls)]
    for (seq, lab), g in runs.groupby(["sequence", "window_label"], sort=True):
        per = g.set_index("controller")
        cells = []
        for c in ctrls:
            if c not in per.index:
                cells.append("")
            else:
                r = per.loc[c]
                cell = "tracked" if bool(r.vo_success) else f"lost at {int(r.vo_failed_at)}"
                if "vo_map_success" in per.columns:
                    cell += " / " + ("tracked" if bool(r.vo_map_success) else f"lost at {int(r.vo_map_failed_at)}")
                cells.append(cell)
        lines.append(f"| {seq} ({lab}) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def timing_table(runs: pd.DataFrame) -> str:
    ctrls = ordered(set(runs.controller))
    lines = ["| Method | controller update, median (ms) | wall time per frame incl. rendering + matching (s) |",
             "|---|---:|---:|"]
    for c in ctrls:
        r = runs[runs.controller == c]
        lines.append(f"| {label(c)} | {np.nanmedian(r.controller_ms_median):.1f} | {np.nanmedian(r.seconds_per_frame):.2f} |")
    return "\n".join(lines)


def headline(metrics: dict, runs: pd.DataFrame | None = None) -> list[str]:
    """Sentences comparing the learned controller with AG+AE and the oracle on dynamic sections (and, given the
    runs table, their VO margins: the worst frame pair's tracked inliers over the split's runs)."""
    out = []
    for split in ("validation", "test"):
        m = metrics.get(split) or {}
        if "learned" not in m or "agae" not in m:
            continue
        lrn, ag = m["learned"]["dynamic"], m["agae"]["dynamic"]
        parts = []
        fes = [fe for fe in lrn if not fe.endswith("_sumlog")]
        for fe, name in ((fe, frontend_label(fe)) for fe in fes):
            a, b = lrn[fe]["min_nfm"], ag[fe]["min_nfm"]
            c, d = lrn[fe]["median_nfm"], ag[fe]["median_nfm"]
            parts.append(f"{name} median {_fmt(c)} vs {_fmt(d)}, minimum {_fmt(a)} vs {_fmt(b)}")
        line = f"- {split}, dynamic sections, learned vs AG+AE: " + "; ".join(parts)
        if "oracle" in m:
            o = m["oracle"]["dynamic"][fes[0]]
            line += f" (oracle {frontend_label(fes[0])} median {_fmt(o['median_nfm'])}, minimum {_fmt(o['min_nfm'])})"
        t_l, t_a = m["learned"]["tracking_success"], m["agae"]["tracking_success"]
        line += f"; VO tracking {t_l[0]}/{t_l[1]} vs {t_a[0]}/{t_a[1]}"
        if runs is not None:
            worst = runs[runs.route_split == split].groupby("controller").vo_min_inliers.min()
            if {"learned", "agae"} <= set(worst.index):
                line += f" (worst frame pair {worst['learned']:.0f} vs {worst['agae']:.0f} tracked inliers)"
            if "vo_map_success" in runs.columns:
                r = runs[runs.route_split == split]
                ok = r.groupby("controller").vo_map_success.agg(lambda v: f"{int(v.astype(bool).sum())}/{len(v)}")
                if {"learned", "agae"} <= set(ok.index):
                    line += f"; map-tracking VO {ok['learned']} vs {ok['agae']}"
        line += "."
        out.append(line)
    return out


def selection_section(sel: dict) -> list[str]:
    """Markdown for reports/select_model.json: which iteration's network was evaluated, and why."""
    md = ["## Which network was evaluated", "",
          f"The final model is **{sel['chosen']}**'s network ({sel['rule']})."]
    if not sel.get("scores"):
        return md + [""]
    windows = ", ".join(w["sequence"] for w in sel.get("windows", []))
    ref = sel.get("reference") or "the reference"
    md += [f"Every candidate drove the `{sel['city']}` city in closed loop ({windows}), which the evaluation "
           "never drives:", ""]
    rows = list(sel["scores"]) + ([sel["reference_statistics"]] if sel.get("reference_statistics") else [])
    fes = list(rows[0]["dynamic_min_nfm"])
    md += ["| network | VO tracked | " + "".join(f"dynamic min NFM, {frontend_label(fe)} | " for fe in fes)
           + f"EV above {ref} | clipped (median) | score |", "|---|---:|" + "---:|" * len(fes) + "---:|---:|---:|"]
    for s in rows:
        d = s["dynamic_min_nfm"]
        name = f"**{s['name']}**" if s["name"] == sel["chosen"] else s["name"]
        off = s.get("median_offset_ev")
        score = s.get("score")
        clip = s.get("median_saturated_frac")
        md.append(f"| {name} | {s['vo_ok']}/{s['vo_runs']} | " + "".join(f"{_fmt(d.get(fe))} | " for fe in fes) +
                  f"{'—' if off is None else f'{off:+.1f}'} | {'—' if clip is None else f'{100 * clip:.0f} %'} | "
                  f"{'—' if score is None else f'{score:.2f}'} |")
    return md + [""]


def build_report(reports_dir: str | os.PathLike, rcfg: ReportConfig | None = None) -> dict[str, Path]:
    """Write reports/results.md and reports/figures/*.png; return the written paths by name."""
    rcfg = rcfg or ReportConfig()
    reports_dir = Path(reports_dir)
    metrics, frames, runs = load_eval(reports_dir)
    bound = load_bound(reports_dir)
    fig_dir = reports_dir / "figures"
    written: dict[str, Path] = {}
    figs = {
        "fig7_tunnel_timeline": lambda p: tunnel_timeline(frames, p),
        "fig6_image_strips": lambda p: image_strips(frames, reports_dir / "eval" / "thumbs", p, rcfg.strip_split,
                                                    rcfg.strip_portal, rcfg.strip_columns),
    }
    for split in ("validation", "test"):
        figs[f"nfm_bars_{split}_dynamic"] = (lambda s: lambda p: nfm_bars(metrics, p, s, "dynamic"))(split)
    # drawn into a staging directory that replaces reports/figures whole: a figure not drawn this time (no data for
    # it) does not linger from an earlier run (the output is kept across runs: dvc.yaml `persist`)
    with atomic_dir(fig_dir) as staging:
        for name, draw in figs.items():
            if draw(staging / f"{name}.png"):
                written[name] = fig_dir / f"{name}.png"
    n_frames = frames.groupby("run_id").size()
    md = ["# Results: closed-loop evaluation in the simulator", "",
          "Every controller drove the simulated camera over the same windows (same route, lighting, sensor and noise "
          "seeds). NFM = inlier feature matches between consecutive frames (fundamental-matrix RANSAC). Per section "
          "(ground-truth static / dynamic): median and minimum NFM over its frames, then the mean over sections. "
          "(SL) = after the SumLog transform tuned on training pairs. **Bold**: best causal controller per column; "
          "*italics*: references, not competitors: the greedy oracle (sees the next frame and picks one step at a "
          "time; not a bound, a causal controller can beat it) and, when evaluate computed it, the offline optimum "
          "(the best any sequence of its grid's settings scores on each section: a bound for controllers "
          "restricted to that grid, docs/evaluation.md).", "",
          f"Runs: {runs['run_id'].nunique()} ({runs['sequence'].nunique()} windows × "
          f"{runs['controller'].nunique()} controllers), {int(n_frames.sum())} frames "
          f"(median {int(n_frames.median())} per run).", "", "## Headline", ""]
    md += headline(metrics, runs) or ["- (learned or AG+AE not evaluated)"]
    md += ["", f"Paper (real rig, validation, dynamic; shapes only): AG+AE median {PAPER_DYNAMIC['agae'][0]} / "
           f"{PAPER_DYNAMIC['agae'][1]}, minimum {PAPER_DYNAMIC['agae'][2]} / {PAPER_DYNAMIC['agae'][3]}; ours median "
           f"{PAPER_DYNAMIC['learned'][0]} / {PAPER_DYNAMIC['learned'][1]}, minimum {PAPER_DYNAMIC['learned'][2]} / "
           f"{PAPER_DYNAMIC['learned'][3]} (ORB / libviso2).", ""]
    sel_path = reports_dir / "select_model.json"
    if sel_path.is_file():  # written by the select_model stage (absent when evaluate ran on its own)
        try:
            md += selection_section(json.loads(sel_path.read_text()))
        except (ValueError, KeyError, TypeError) as exc:
            raise InputError(f"{sel_path}: not a model-selection report ({exc})") from None
    for num, split in (("I", "validation"), ("II", "test")):
        if split not in metrics:
            continue
        md += [f"## Table {num}: NFM, {SPLIT_TITLE[split]}", "", nfm_table(metrics, split, bound=bound), "",
               "With SumLog (SL):", "", nfm_table(metrics, split, sumlog=True, bound=bound), ""]
    md += ["## Table III: VO tracking successes", "",
           "Monocular frame-to-frame VO (ORB + essential matrix); a run fails when the tracked inliers of a frame pair "
           "fall below the threshold at any frame. Map-tracking VO (`expoctl.vo_map`): each frame is tracked against "
           "a local map of points triangulated between keyframes, with ORB-SLAM2's thresholds (lost below 30 map "
           "inliers after pose refinement); it is the closer model of the paper's ORB-SLAM2. ATE: RMSE after rigid "
           "alignment, scale from ground truth, over successful runs.", "", tracking_table(metrics, runs), "", "Per window:", "", runs_table(runs), "",
           "VO margin: the tracked-inlier count of each run's worst frame pair, i.e. the strictest threshold at which "
           "the run would still have tracked (this VO matches frame to frame; ORB-SLAM2 tracks map points from older "
           "keyframes and loses track earlier). Runs tracked at stricter thresholds pool both cities.", "",
           vo_margin_table(runs), "",
           *(["Map-tracking VO margin: each run's fewest map inliers on a scored frame (a lost run: the count where "
              "it was lost).", "", vo_margin_table(runs, (30, 50, 75, 100, 150), "vo_map_min_inliers"), ""]
             if "vo_map_min_inliers" in runs.columns else []),
           "## Timing", "", timing_table(runs), "", "## Figures", ""]
    captions = {
        "fig7_tunnel_timeline": "Fig. 7 analogue: NFM (ORB, libviso2-style) and gain / exposure per frame through a "
                                "tunnel entry and exit, all controllers (grey: dynamic section).",
        "fig6_image_strips": "Fig. 6 analogue: frames around a tunnel exit, one row per controller, ORB NFM under each.",
        "nfm_bars_validation_dynamic": "Validation, dynamic sections: median and minimum NFM per controller.",
        "nfm_bars_test_dynamic": "Test, dynamic sections: median and minimum NFM per controller.",
    }
    for name, p in written.items():
        md += [f"![{name}](figures/{p.name})", "", captions.get(name, name), ""]
    from expoctl.io import write_text

    write_text("\n".join(md), reports_dir / "results.md")
    written["results"] = reports_dir / "results.md"
    return written
