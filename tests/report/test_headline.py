from __future__ import annotations

import math

import pandas as pd

from expoctl.report.headline import headline_metrics


def _entry(orb_min, viso_min, ok, n):
    nfm = lambda m: {"median_nfm": None if m is None else m + 10.0, "min_nfm": m}  # noqa: E731
    return {"static": {}, "dynamic": {"orb": nfm(orb_min), "viso": nfm(viso_min), "orb_sumlog": nfm(0.0),
                                      "viso_sumlog": nfm(0.0)}, "tracking_success": [ok, n]}


def test_headline_takes_the_dynamic_minima_and_counts_vo_per_controller():
    metrics = {"validation": {"learned": _entry(112.5, 81.0, 2, 2), "agae": _entry(18.5, 33.5, 1, 2),
                              "shin": _entry(1.0, 1.0, 0, 2)},
               "test": {"learned": _entry(142.0, 151.0, 2, 2), "agae": _entry(54.0, None, 2, 2)}}
    runs = pd.DataFrame({"controller": ["learned"] * 4 + ["agae"] * 4 + ["shin"] * 4,
                         "vo_success": [1, 1, 1, 1, 1, 0, 1, 1, 0, 0, 0, 0],
                         "vo_map_success": [True, True, True, False, False, False, True, False] + [False] * 4})
    h = headline_metrics(metrics, runs, 0.0403)
    assert h["val_loss"] == 0.0403
    assert h["dynamic_min_nfm"] == {"validation": {"orb": {"learned": 112.5, "agae": 18.5},
                                                   "viso": {"learned": 81.0, "agae": 33.5}},
                                    "test": {"orb": {"learned": 142.0, "agae": 54.0},
                                             "viso": {"learned": 151.0, "agae": None}}}
    assert h["vo_tracked"] == {"learned": {"frame_to_frame": 4, "map": 3, "runs": 4},
                               "agae": {"frame_to_frame": 3, "map": 1, "runs": 4}}  # shin is not a headline


def test_headline_leaves_out_what_was_not_evaluated():
    metrics = {"validation": {"agae": _entry(18.5, 33.5, 1, 2)}}
    runs = pd.DataFrame({"controller": ["agae", "agae"], "vo_success": [1, 0]})
    h = headline_metrics(metrics, runs, math.nan)
    assert h == {"val_loss": None, "dynamic_min_nfm": {"validation": {"orb": {"agae": 18.5}, "viso": {"agae": 33.5}}},
                 "vo_tracked": {"agae": {"frame_to_frame": 1, "runs": 2}}}
