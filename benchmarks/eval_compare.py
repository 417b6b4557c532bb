"""Paired comparison of controllers from evaluate outputs (not a test): the error bars and brightness figures in docs/.

Every controller of an evaluation drives the same windows with the same seeds, so per dynamic section the minimum NFM
of a controller and of AG+AE form a pair. This prints, per city and front end, the mean minimum NFM of each controller,
the paired difference to AG+AE (mean ± standard error over sections) and how many sections it won; then per
controller the median exposure product (EV), grey level, clipped share and gain over all recorded frames; then how
deep each controller's worst transition goes (mean dynamic-section minimum ORB NFM over mean static-section median,
next to the paper's Table I, where ORB-SLAM2 lost track with AG+AE at 0.09 and kept it with theirs at 0.16); then
the VO margin table of the report (each run's worst frame pair) over the pooled runs, and, for evaluations that
ran it, the map-tracking VO's successes and margins (each run's fewest map inliers), how fast its map fills, and
its margins scored from frame 8 (the tracker's bootstrap length) without runs lost before then.

    .venv/bin/python benchmarks/eval_compare.py [REPORTS_DIR ...]     (default: reports; each holds eval/)

Several directories are pooled (e.g. runs over different traversals); a directory given as DIR:NAME contributes only
its `learned` controller, renamed NAME (e.g. the iteration-1 network evaluated separately).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
# Tomasi et al. Table I (London validation, ORB): static median, dynamic median, dynamic minimum NFM, averaged over
# sequences; ORB-SLAM2 tracked 0/6 runs with AG+AE and 6/6 with their network (Table III)
PAPER_ORB = {"AG+AE (paper)": (593, 393, 54), "ours (paper)": (600, 395, 98)}


def load(specs: list[str], table: str) -> pd.DataFrame:
    parts = []
    for spec in specs:
        path, _, rename = spec.partition(":")
        f = Path(path) / "eval" / f"{table}.parquet"
        if not f.is_file():
            raise SystemExit(f"eval_compare: {f} not found (run the evaluate stage first)")
        df = pd.read_parquet(f)
        if rename:
            df = df[df["controller"] == "learned"].assign(controller=rename)
        parts.append(df)
    return pd.concat(parts, ignore_index=True)


def transition_depth(sections: pd.DataFrame) -> str:
    """Per city and controller: mean static median, mean dynamic median and mean dynamic minimum ORB NFM over
    sections, and the last over the first (how far the worst frame pair of a transition falls below open-road
    matching), with the paper's validation figures for scale."""
    rows = [f"{'city':10s} {'controller':16s} {'static median':>13s} {'dyn median':>10s} {'dyn min':>8s} "
            f"{'min / static':>12s}"]
    for split in ("validation", "test"):
        for ctrl in sorted(sections["controller"].unique()):
            x = sections[(sections["route_split"] == split) & (sections["controller"] == ctrl)]
            st, dy = x[x["section"] == "static"], x[x["section"] == "dynamic"]
            if st.empty or dy.empty:
                continue
            s_med, d_med, d_min = st["median_nfm_orb"].mean(), dy["median_nfm_orb"].mean(), dy["min_nfm_orb"].mean()
            rows.append(f"{split:10s} {ctrl:16s} {s_med:13.0f} {d_med:10.0f} {d_min:8.0f} {d_min / s_med:12.3f}")
    for name, (s_med, d_med, d_min) in PAPER_ORB.items():
        rows.append(f"{'London':10s} {name:16s} {s_med:13d} {d_med:10d} {d_min:8d} {d_min / s_med:12.3f}")
    return "\n".join(rows)


def main() -> int:
    specs = sys.argv[1:] or [str(ROOT / "reports")]
    all_sections = load(specs, "sections")
    sections = all_sections
    sections = sections[sections["section"] == "dynamic"].set_index(["route_split", "sequence", "section_id"])
    ref = sections[sections["controller"] == "agae"]
    if ref.empty:
        raise SystemExit("eval_compare: no agae runs to pair with")
    print(f"{'controller':16s} {'city':10s} {'front end':9s} {'min NFM':>8s} {'AG+AE':>7s} {'paired diff':>15s} wins")
    for ctrl in [c for c in sections["controller"].unique() if c != "agae"]:
        other = sections[sections["controller"] == ctrl]
        for split in ("validation", "test"):
            for fe in ("orb", "viso"):
                col = f"min_nfm_{fe}"
                a = ref[ref.index.get_level_values(0) == split][col]
                b = other[col].reindex(a.index)
                if b.isna().any() or a.empty:
                    continue
                d = (b - a).to_numpy(float)
                se = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else float("nan")
                print(f"{ctrl:16s} {split:10s} {fe:9s} {b.mean():8.1f} {a.mean():7.1f} {d.mean():+7.1f} ± {se:5.1f} "
                      f"{int((d > 0).sum())}/{d.size}")
    frames = load(specs, "frames")
    # exposure product in stops above 1 µs at 0 dB: the brightness the settings ask for
    frames["ev"] = np.log2(frames["exposure_us"]) + frames["gain_db"] / (20.0 * np.log10(2.0))
    stats = frames.groupby(["route_split", "controller"]).agg(median_ev=("ev", "median"),
        median_grey=("mean_grey", "median"), median_clipped=("saturated_frac", "median"),
        median_gain_db=("gain_db", "median"))
    print()
    print(stats.round(2).to_string())
    print()
    print(transition_depth(all_sections))
    # VO margin over the pooled runs: each run's worst frame pair (tracked inliers), runs tracked at stricter thresholds
    from expoctl.report.results import vo_margin_table

    runs = load(specs, "runs")
    print()
    print(vo_margin_table(runs))
    if "vo_map_min_inliers" in runs.columns:
        # the local-map tracker (expoctl.vo.local_map): successes per city, then each run's fewest map inliers
        print()
        print(runs.groupby(["route_split", "controller"]).vo_map_success.agg(
            lambda v: f"{int(v.astype(bool).sum())}/{len(v)}").rename("map-tracking VO successes").to_string())
        print()
        print(vo_margin_table(runs, (30, 50, 75, 100, 150), "vo_map_min_inliers"))
        print()
        print(map_fill_and_late_margins(frames, runs, MAP_SCORED_FROM))
    return 0


#: the map tracker's default bootstrap length (expoctl.vo.local_map): frames before it only build the map
MAP_SCORED_FROM = 8


def map_fill_and_late_margins(frames: pd.DataFrame, runs: pd.DataFrame, first: int) -> str:
    """How fast the map fills (median map inliers over runs by frame index), then the map-VO margins scored from frame
    `first` on, leaving out runs that were lost before it (evaluations made with a shorter bootstrap)."""
    from expoctl.report.results import vo_margin_table

    fill = frames[frames.frame <= 10].groupby("frame").vo_map_n_inliers.median()
    lines = ["median map inliers by frame: " + ", ".join(f"{int(k)}: {v:.0f}" for k, v in fill.dropna().items())]
    early = runs[(runs.vo_map_failed_at >= 0) & (runs.vo_map_failed_at < first)]
    lost = []
    for r in early.itertuples():
        f = frames[(frames.run_id == r.run_id) & (frames.frame == r.vo_map_failed_at)].iloc[0]
        lost.append(f"{r.run_id} at frame {int(r.vo_map_failed_at)} ({f.portal_kind} {f.portal_dt_s:+.1f} s, {f.section}, "
                    f"{100 * f.saturated_frac:.0f} % clipped, {f.vo_map_n_inliers:.0f} map inliers)")
    lines.append(f"runs lost before frame {first} (left out): " + ("; ".join(lost) or "none"))
    late = frames[(frames.frame >= first) & ~frames.run_id.isin(early.run_id)]
    worst = late.groupby("run_id").vo_map_n_inliers.min().rename("vo_map_min_inliers")
    kept = runs.drop(columns="vo_map_min_inliers").merge(worst, left_on="run_id", right_index=True)
    lines += ["", f"map-tracking VO margin, scored from frame {first}:",
              vo_margin_table(kept, (30, 50, 75, 100, 150), "vo_map_min_inliers")]
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
