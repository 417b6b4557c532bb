"""reports/headline.json: the dozen numbers that say how a run went, DVC's only metric.

`dvc metrics show` and `dvc exp show` print every number of a metrics file as a column; the full tables
(reports/metrics.json, reports/eval/) have about 300, which makes two experiments unreadable side by side. This file
keeps what the paper's headline compares, learned controller vs AG+AE:

    {"val_loss": <the evaluated network's validation loss>,
     "dynamic_min_nfm": {<city>: {"orb" | "viso": {"learned": x, "agae": y}}},
     "vo_tracked": {"learned" | "agae": {"frame_to_frame": n, "map": n, "runs": n}}}

`dynamic_min_nfm` is metrics.json's mean over dynamic sections of the per-section minimum of inlier feature matches
between consecutive frames; `vo_tracked` counts the evaluation runs (windows × cities) each controller's VO tracked
to the end, frame to frame and against the local map, out of its `runs`. A controller that was not
evaluated is left out; a value with no qualifying section is null.
"""

from __future__ import annotations

import math

import pandas as pd

HEADLINE_CONTROLLERS = ("learned", "agae")
HEADLINE_CITIES = ("validation", "test")


def headline_metrics(metrics: dict, runs: pd.DataFrame, val_loss: float | None) -> dict:
    """The headline numbers from metrics.json, the runs table and the final network's validation loss."""
    out: dict = {"val_loss": None if val_loss is None or not math.isfinite(val_loss) else float(val_loss)}
    nfm: dict = {}
    for city in HEADLINE_CITIES:
        m = metrics.get(city) or {}
        present = [c for c in HEADLINE_CONTROLLERS if c in m]
        fes = [fe for fe in m[present[0]]["dynamic"] if not fe.endswith("_sumlog")] if present else []
        per_fe = {fe: {c: m[c]["dynamic"][fe]["min_nfm"] for c in present} for fe in fes}
        if any(per_fe.values()):
            nfm[city] = per_fe
    out["dynamic_min_nfm"] = nfm
    vo: dict = {}
    for c in HEADLINE_CONTROLLERS:
        r = runs[runs["controller"] == c]
        if r.empty:
            continue
        vo[c] = {"frame_to_frame": int(r["vo_success"].astype(bool).sum())}
        if "vo_map_success" in r.columns:
            vo[c]["map"] = int(r["vo_map_success"].astype(bool).sum())
        vo[c]["runs"] = int(len(r))
    out["vo_tracked"] = vo
    return out
