"""Paired comparison of controllers from evaluate outputs (not a test): the README's error bars and brightness figures.

Every controller of an evaluation drives the same windows with the same seeds, so per dynamic section the minimum NFM
of a controller and of AG+AE form a pair. This prints, per city and front end, the mean minimum NFM of each controller,
the paired difference to AG+AE (mean ± standard error over sections) and how many sections it won; then per
controller the median exposure product (EV), grey level, clipped share and gain over all recorded frames; then the
VO margin table of the report (each run's worst frame pair) over the pooled runs.

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


def main() -> int:
    specs = sys.argv[1:] or [str(ROOT / "reports")]
    sections = load(specs, "sections")
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
    # VO margin over the pooled runs: each run's worst frame pair (tracked inliers), runs tracked at stricter thresholds
    from expoctl.report import vo_margin_table

    print()
    print(vo_margin_table(load(specs, "runs")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
