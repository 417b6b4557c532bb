"""One row per pipeline seed: what issue 25 asks of each (not a test).

For each pipeline checkout (after `dvc repro` with `overrides: ["seed=N", ...]`) this reads reports/ and prints:
the chosen network and the saturation probe's verdict on every candidate (the probe is a check: a seed passes when
the last iteration's network keeps its fixed points below the probe's clipped-share line, i.e. the choice with the
probe off would be the same), val loss and `val_follow` of the final network, the four dynamic-section minima
(ours / AG+AE, mean over sections of traversal 0's windows, ORB and libviso2-style, validation and test cities),
VO successes of both (frame to frame; against the map), and the median exposure-product offset of ours from AG+AE
over every frame they both drove (EV, paired frame by frame).

    .venv/bin/python benchmarks/archive/seed_summary.py [--json OUT] [--prior JSON] SEED=DIR [SEED=DIR ...]

`--prior` adds the rows of an earlier `--json` output for seeds whose checkouts are gone (a seed given as SEED=DIR
replaces its prior row).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path.insert(0, str(ROOT / "src"))

from expoctl.camera.ranges import exposure_value_ev  # noqa: E402

CITIES = ("validation", "test")
FRONT_ENDS = (("orb", "ORB"), ("viso", "viso"))
PAIR_KEYS = ["route_split", "sequence", "frame"]


def seed_row(seed: str, root: Path) -> dict:
    rep = root / "reports"
    sel = json.loads((rep / "select_model.json").read_text())
    chosen = sel["chosen"]
    probe = sel.get("probe", {}).get("results", {})
    last = max(sel["candidates"], key=lambda c: c["iteration"])["name"]
    train_json = rep / ("train.json" if chosen == "iteration1" else f"iter{chosen[-1]}/train.json")
    tr = json.loads(train_json.read_text())
    row = {"seed": seed, "chosen": chosen, "last_iteration": last,
           "probe": {k: bool(v.get("passes")) for k, v in probe.items()},
           "probe_max_clipped": {k: max(s["final_saturated_frac"] for st in v["starts"].values() for s in st)
                                 for k, v in probe.items()},
           # black share: recorded since the probe's dark line (3c237c7); None for earlier runs
           "probe_max_dark": {k: v.get("worst_dark_frac") for k, v in probe.items()},
           # the controller that drove camera 1 in iteration 2 (the reference gate's decision; before it: learned)
           "iteration2_reference": _iteration2_reference(rep),
           "val_loss": tr["val_loss"], "val_follow": tr["val_follow"],
           # open-loop signs of a collapse to "hold the input settings", known before any closed loop
           "hold_val_loss": tr.get("hold_val_loss"), "best_epoch": tr.get("best_epoch")}
    sections = pd.read_parquet(rep / "eval" / "sections.parquet")
    dyn = sections[sections["section"] == "dynamic"]
    for city in CITIES:
        d = dyn[dyn["route_split"] == city]
        for fe, name in FRONT_ENDS:
            piv = d.pivot_table(index=["sequence", "section_id"], columns="controller", values=f"min_nfm_{fe}")
            ours, ref = piv["learned"], piv["agae"]
            row[f"{city}_{name}_min"] = [float(ours.mean()), float(ref.mean())]
            row[f"{city}_{name}_won"] = f"{int((ours > ref).sum())}/{len(piv)}"
    runs = pd.read_parquet(rep / "eval" / "runs.parquet")
    for ctrl in ("learned", "agae"):
        r = runs[runs["controller"] == ctrl]
        vo = f"{int(r['vo_success'].sum())}/{len(r)}"
        vm = f"{int(r['vo_map_success'].sum())}/{len(r)}"
        row[f"vo_{ctrl}"] = f"{vo}; {vm}"
    fr = pd.read_parquet(rep / "eval" / "frames.parquet")
    fr = fr.assign(ev=exposure_value_ev(fr["gain_db"], fr["exposure_us"]))
    paired = fr[fr.controller == "learned"][PAIR_KEYS + ["ev"]].merge(
        fr[fr.controller == "agae"][PAIR_KEYS + ["ev"]], on=PAIR_KEYS, suffixes=("_ours", "_agae"))
    for city in CITIES:
        p = paired[paired["route_split"] == city]
        row[f"{city}_ev_offset"] = float(np.median(p["ev_ours"] - p["ev_agae"]))
    return row


def _iteration2_reference(rep: Path) -> str:
    gate = rep / "iter2" / "collect_reference.json"
    if not gate.is_file():
        return "learned (no gate)"
    return json.loads(gate.read_text())["reference_controller"]


def _probe_cell(row: dict, k: str, passes: bool) -> str:
    dark = (row.get("probe_max_dark") or {}).get(k)
    black = "" if dark is None else f" / {dark:.0%} black"
    return f"{k[-1]}: {'pass' if passes else 'FAIL'} {row['probe_max_clipped'][k]:.0%} white{black}"


def _vs_hold(row: dict) -> str:
    """Validation loss over the hold-the-inputs predictor's; above 1 the network is worse than holding."""
    if row.get("hold_val_loss") is None:
        return "—"
    return f"{row['val_loss'] / row['hold_val_loss']:.2f} ({row['best_epoch']})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", help="SEED=DIR: a pipeline checkout whose reports/ the seed's run wrote")
    ap.add_argument("--json", help="write the rows here")
    ap.add_argument("--prior", help="an earlier --json output: its rows for seeds not given here are kept")
    args = ap.parse_args(argv)
    rows, problems = [], []
    for spec in args.runs:
        seed, sep, d = spec.partition("=")
        if not sep or not (Path(d) / "reports" / "select_model.json").is_file():
            problems.append(f"{spec}: expected SEED=DIR with DIR/reports/select_model.json")
            continue
        rows.append(seed_row(seed, Path(d)))
    if args.prior:
        try:
            prior = json.loads(Path(args.prior).read_text())
        except (OSError, ValueError) as exc:
            problems.append(f"{args.prior}: cannot read the prior rows ({exc})")
            prior = []
        given = {r["seed"] for r in rows}
        rows = [r for r in prior if r.get("seed") not in given] + rows
        # numeric seeds in order, then named runs (e.g. "1-nogate") by name
        rows.sort(key=lambda r: (0, int(r["seed"]), "") if str(r["seed"]).isdigit() else (1, 0, str(r["seed"])))
    if problems:
        print("seed_summary: " + "\n  ".join(problems), file=sys.stderr)
        return 2
    print("| seed | it. 2 camera 1 | chosen (probe on every candidate) | val loss | follow | val ORB | val viso | test ORB | test viso "
          "| VO ours (f2f; map) | VO AG+AE | EV offset val / test | val loss / hold (best epoch) |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---|---|---:|---:|")
    for r in rows:
        mins = " | ".join(f"{r[f'{c}_{n}_min'][0]:.0f} / {r[f'{c}_{n}_min'][1]:.0f} ({r[f'{c}_{n}_won']})"
                          for c in CITIES for _, n in FRONT_ENDS)
        probe = ", ".join(_probe_cell(r, k, v) for k, v in r["probe"].items())
        print(f"| {r['seed']} | {r.get('iteration2_reference', 'learned (no gate)')} | {r['chosen']} ({probe}) | {r['val_loss']:.4f} | {r['val_follow']:.2f} | {mins} "
              f"| {r['vo_learned']} | {r['vo_agae']} | {r['validation_ev_offset']:+.2f} / {r['test_ev_offset']:+.2f} "
              f"| {_vs_hold(r)} |")
    if args.json:
        out = Path(args.json)
        tmp = out.with_suffix(out.suffix + ".tmp")
        tmp.write_text(json.dumps(rows, indent=1) + "\n")
        tmp.replace(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
