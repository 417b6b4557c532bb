"""The paper's Tables I–III from pooled evaluations, with paired differences against AG+AE (not a test).

Every controller of an evaluation drives the same windows with the same seeds, so each section (static or dynamic)
of a window gives one paired observation per controller. Per site (city or scenario), front end (ORB, libviso2-style,
each with and without SumLog) and controller this prints the mean over sections of the static and dynamic median and
minimum NFM, then for each controller against AG+AE the paired difference (mean ± standard error over sections) and
how many sections it won. Then VO (Table III): frame-to-frame and map-tracking successes per site and controller,
and the windows that a controller tracked where AG+AE lost track.

    .venv/bin/python benchmarks/paper_tables.py [--md OUT.md] [--json OUT.json] DIR[@SITE] [DIR[@SITE] ...]

DIR holds an evaluation's eval/ (a `reports` directory). Without @SITE its windows keep their route split
(validation, test) as the site; with @SITE all its windows count as SITE (a scenario run as the test city, e.g.
`reports_underpass@underpass`). Several DIRs may feed one site (e.g. traversal 0 from the pipeline, 1–5 from a
second evaluation); a (site, window, controller) given twice is an error. Writes benchmarks/results/paper_tables.json
unless --json says otherwise.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "src"), str(ROOT)]

from bench_meta import run_metadata  # noqa: E402

from expoctl.io import write_json, write_text  # noqa: E402
from expoctl.report.figures import label, ordered  # noqa: E402

FRONTENDS = ("orb", "viso", "orb_sumlog", "viso_sumlog")
FRONTEND_TITLE = {"orb": "ORB", "viso": "libviso2-style", "orb_sumlog": "ORB + SumLog",
                  "viso_sumlog": "libviso2-style + SumLog"}
COLUMNS = (("static", "median"), ("static", "min"), ("dynamic", "median"), ("dynamic", "min"))
REFERENCE = "agae"
#: the issue's targets for ours over AG+AE, dynamic minimum NFM (the paper's Table I/II ratios)
TARGET_RATIO = {"orb": 1.5, "viso": 1.2}


def load(specs: list[str]) -> tuple[pd.DataFrame, pd.DataFrame]:
    sections, runs = [], []
    for spec in specs:
        path, _, site = spec.partition("@")
        eval_dir = Path(path) / "eval"
        for name in ("sections", "runs"):
            if not (eval_dir / f"{name}.parquet").is_file():
                raise SystemExit(f"paper_tables: {eval_dir / (name + '.parquet')} not found (run the evaluation first)")
        s, r = pd.read_parquet(eval_dir / "sections.parquet"), pd.read_parquet(eval_dir / "runs.parquet")
        for df in (s, r):
            df["site"] = site or df["route_split"]
            df["source"] = path
        sections.append(s)
        runs.append(r)
    runs_all = pd.concat(runs, ignore_index=True)
    dup = runs_all.duplicated(["site", "sequence", "controller"], keep=False)
    if dup.any():
        first = runs_all[dup].iloc[0]
        raise SystemExit(f"paper_tables: window {first.sequence} of site {first.site}, controller {first.controller}, "
                         f"is in more than one directory ({', '.join(sorted(runs_all[dup].source.unique()))})")
    return pd.concat(sections, ignore_index=True), runs_all


def paired(sections: pd.DataFrame, site: str, ctrl: str, kind: str, stat: str, fe: str,
           reference: str = REFERENCE) -> dict | None:
    """Paired difference of `ctrl` minus `reference` over the sections both have."""
    col = f"{stat}_nfm_{fe}"
    x = sections[(sections.site == site) & (sections.section == kind)]
    a = x[x.controller == reference].set_index(["sequence", "section_id"])[col]
    b = x[x.controller == ctrl].set_index(["sequence", "section_id"])[col]
    both = pd.concat([a.rename("ref"), b.rename("ctl")], axis=1, join="inner").dropna()
    if both.empty:
        return None
    d = (both.ctl - both.ref).to_numpy(float)
    return {"n": int(d.size), "mean": float(both.ctl.mean()), "reference_mean": float(both.ref.mean()),
            "diff": float(d.mean()), "se": float(d.std(ddof=1) / np.sqrt(d.size)) if d.size > 1 else None,
            "wins": int((d > 0).sum()), "ties": int((d == 0).sum())}


def nfm_tables(sections: pd.DataFrame, sites: list[str]) -> tuple[list[str], dict]:
    md, out = [], {}
    for site in sites:
        s_site = sections[sections.site == site]
        ctrls = ordered(set(s_site.controller))
        n_win = s_site.groupby("controller").sequence.nunique()
        out[site] = {}
        for fe in FRONTENDS:
            if f"min_nfm_{fe}" not in s_site.columns:
                continue
            md += [f"### {site}, {FRONTEND_TITLE[fe]}", "",
                   "| controller | windows | " + " | ".join(f"{k} {s}" for k, s in COLUMNS) + " |",
                   "|---|---:|" + "---:|" * len(COLUMNS)]
            means = {}
            for c in ctrls:
                cells = []
                for kind, stat in COLUMNS:
                    v = s_site[(s_site.controller == c) & (s_site.section == kind)][f"{stat}_nfm_{fe}"].dropna()
                    means[(c, kind, stat)] = float(v.mean()) if len(v) else None
                    cells.append(f"{v.mean():.0f}" if len(v) else "—")
                md.append(f"| {label(c)} | {n_win.get(c, 0)} | " + " | ".join(cells) + " |")
            md += ["", f"Paired against AG+AE (mean difference ± standard error over sections; sections won):", "",
                   "| controller | " + " | ".join(f"{k} {s}" for k, s in COLUMNS) + " |",
                   "|---|" + "---:|" * len(COLUMNS)]
            out[site][fe] = {"means": {f"{c}/{k}/{s}": v for (c, k, s), v in means.items()}, "paired": {}}
            for c in ctrls:
                if c == REFERENCE:
                    continue
                cells = []
                for kind, stat in COLUMNS:
                    p = paired(sections, site, c, kind, stat, fe)
                    out[site][fe]["paired"][f"{c}/{kind}/{stat}"] = p
                    if p is None:
                        cells.append("—")
                    else:
                        se = "" if p["se"] is None else f" ± {p['se']:.0f}"
                        cells.append(f"{p['diff']:+.0f}{se} ({p['wins']}/{p['n']})")
                md.append(f"| {label(c)} | " + " | ".join(cells) + " |")
            md.append("")
    return md, out


def ratio_table(sections: pd.DataFrame, nfm: dict, sites: list[str]) -> tuple[list[str], dict]:
    """Ours over AG+AE, dynamic minimum NFM, against the targets; and the gap to the oracle, paired over the windows
    the oracle ran (it may run on fewer)."""
    md = ["| site | front end | ours / AG+AE, dynamic minimum | target | ours − oracle, dynamic minimum (paired; sections) |",
          "|---|---|---:|---:|---:|"]
    out = {}
    for site in sites:
        for fe in ("orb", "viso"):
            m = nfm.get(site, {}).get(fe, {}).get("means", {})
            ours, ref = (m.get(f"{c}/dynamic/min") for c in ("learned", REFERENCE))
            if ours is None or not ref:
                continue
            r = ours / ref
            g = paired(sections, site, "learned", "dynamic", "min", fe, reference="oracle")
            gap = "—" if g is None else (f"{g['diff']:+.0f}" + ("" if g["se"] is None else f" ± {g['se']:.0f}")
                                         + f" ({g['n']})")
            out[f"{site}/{fe}"] = {"ratio": r, "target": TARGET_RATIO[fe], "met": r >= TARGET_RATIO[fe],
                                   "ours_minus_oracle": g}
            md.append(f"| {site} | {FRONTEND_TITLE[fe]} | {r:.2f} | ≥ {TARGET_RATIO[fe]} | {gap} |")
    return md, out


def vo_tables(runs: pd.DataFrame, sites: list[str]) -> tuple[list[str], dict]:
    md = ["| site | controller | VO frame to frame | VO against the map | tracked where AG+AE lost (f2f; map) |",
          "|---|---|---:|---:|---:|"]
    out = {}
    for site in sites:
        r = runs[runs.site == site]
        ref = r[r.controller == REFERENCE].set_index("sequence")
        for c in ordered(set(r.controller)):
            x = r[r.controller == c].set_index("sequence")
            f2f = x.vo_success.astype(bool)
            mp = x.vo_map_success.astype(bool) if "vo_map_success" in x else None
            rescue = []
            for col in ("vo_success", "vo_map_success"):
                if col not in x or c == REFERENCE:
                    rescue.append(None)
                    continue
                lost = ref.index[~ref[col].astype(bool)]
                lost = [w for w in lost if w in x.index]
                rescue.append((int(x.loc[lost, col].astype(bool).sum()), len(lost)))
            out[f"{site}/{c}"] = {"vo": [int(f2f.sum()), len(f2f)],
                                  "vo_map": None if mp is None else [int(mp.sum()), len(mp)],
                                  "tracked_where_agae_lost": rescue}
            cell = "—" if c == REFERENCE else "; ".join("—" if v is None else f"{v[0]}/{v[1]}" for v in rescue)
            md.append(f"| {site} | {label(c)} | {int(f2f.sum())}/{len(f2f)} | "
                      f"{'—' if mp is None else f'{int(mp.sum())}/{len(mp)}'} | {cell} |")
    return md, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="+", help="DIR[@SITE]: a directory holding eval/ (see the module doc)")
    ap.add_argument("--md", type=Path, help="also write the tables as Markdown here")
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "paper_tables.json")
    args = ap.parse_args(argv)
    sections, runs = load(args.dirs)
    sites = list(dict.fromkeys(runs.site))
    nfm_md, nfm = nfm_tables(sections, sites)
    ratio_md, ratio = ratio_table(sections, nfm, sites)
    vo_md, vo = vo_tables(runs, sites)
    windows = runs.groupby(["site", "controller"]).sequence.nunique()
    md = ["# Tables I–III from pooled evaluations", "",
          "Sources: " + ", ".join(f"`{d}`" for d in args.dirs) + ".", "",
          "Windows per site and controller: " + "; ".join(f"{s} {c} {n}" for (s, c), n in windows.items()) + ".", "",
          "## Ours over AG+AE (targets from the paper)", "", *ratio_md, "",
          "## Table III: VO", "", *vo_md, "",
          "## Tables I–II: NFM (mean over sections)", "", *nfm_md]
    text = "\n".join(md) + "\n"
    print(text)
    if args.md:
        write_text(text, args.md)
    write_json({"sources": args.dirs, "ratio": ratio, "vo": vo, "nfm": nfm, **run_metadata()}, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
