"""Sections, per-section statistics and metrics.json (docs/evaluation.md schema) from hand-made frame rows."""

from __future__ import annotations

import copy
import json

import numpy as np
import pandas as pd
import pytest

from expoctl.evaluation.aggregate import add_section_ids, build_metrics, section_stats, validate_metrics
from expoctl.controllers.registry import controller_names

CONTROLLER_NAMES = controller_names()  # every registered controller
from expoctl.evaluation.run import variants

VARIANTS = variants(("orb", "viso"))


def _frames(controller, split, nfm_orb, sections, run_id=None, seq="s1"):
    n = len(nfm_orb)
    d = {"run_id": run_id or f"{seq}-{controller}", "route_split": split, "controller": controller, "sequence": seq,
         "frame": np.arange(n), "section": sections}
    for i, v in enumerate(VARIANTS):
        d[f"nfm_{v}"] = np.asarray(nfm_orb, float) * (i + 1)  # variants scaled so each column is distinct
    return pd.DataFrame(d)


def test_sections_are_maximal_runs_per_run():
    f = _frames("agae", "validation", [np.nan, 1, 2, 3, 4, 5], ["static", "static", "dynamic", "dynamic", "static",
                                                                  "static"])
    assert add_section_ids(f)["section_id"].tolist() == [0, 0, 1, 1, 2, 2]


def test_section_stats_and_metrics_exact():
    sec = ["static"] * 4 + ["dynamic"] * 4
    a = _frames("agae", "validation", [np.nan, 100, 80, 90, 10, 0, 30, 50], sec)
    b = _frames("agae", "validation", [np.nan, 200, 220, 210, 40, 60, 20, 80], sec, seq="s2")
    frames = pd.concat([a, b])
    s = section_stats(frames, min_section_frames=3)
    # s1 static: pairs 100, 80, 90 → median 90, min 80; s1 dynamic: 10, 0, 30, 50 → median 20, min 0
    s1 = s[s.sequence == "s1"].set_index("section")
    assert (s1.loc["static", "median_nfm_orb"], s1.loc["static", "min_nfm_orb"]) == (90.0, 80.0)
    assert (s1.loc["dynamic", "median_nfm_orb"], s1.loc["dynamic", "min_nfm_orb"]) == (20.0, 0.0)
    assert s1.loc["dynamic", "median_nfm_viso"] == 40.0  # the viso column is 2× the ORB one here
    runs = pd.DataFrame({"route_split": ["validation"] * 2, "controller": ["agae"] * 2, "vo_success": [True, False]})
    m = build_metrics(s, runs)
    # s2 dynamic: 40, 60, 20, 80 → median 50, min 20; mean over sections: median (20+50)/2, min (0+20)/2
    assert m["validation"]["agae"]["dynamic"]["orb"] == {"median_nfm": 35.0, "min_nfm": 10.0}
    assert m["validation"]["agae"]["static"]["orb"] == {"median_nfm": (90 + 210) / 2, "min_nfm": (80 + 200) / 2}
    assert m["validation"]["agae"]["tracking_success"] == [1, 2]
    assert validate_metrics(m, ["agae"], ["validation"]) == []
    json.dumps(m)  # plain JSON types only


def test_short_sections_are_left_out():
    f = _frames("agae", "test", [np.nan, 5, 6, 100, 100, 100, 100], ["dynamic"] * 3 + ["static"] * 4)
    s = section_stats(f, min_section_frames=3)
    assert s["section"].tolist() == ["static"]  # the dynamic section has only 2 pairs


def _valid_metrics():
    entry = {k: {v: {"median_nfm": 10.0, "min_nfm": 2.0} for v in VARIANTS} for k in ("static", "dynamic")}
    entry["tracking_success"] = [1, 2]
    return {s: {c: copy.deepcopy(entry) for c in CONTROLLER_NAMES} for s in ("validation", "test")}


def test_schema_accepts_the_full_contract():
    assert validate_metrics(_valid_metrics()) == []


@pytest.mark.parametrize("breaker, fragment", [
    (lambda m: m.pop("test"), "missing route split 'test'"),
    (lambda m: m["validation"].pop("oracle"), "validation.oracle: missing"),
    (lambda m: m["validation"]["learned"]["dynamic"].pop("viso_sumlog"), "front ends"),
    (lambda m: m["test"]["agae"]["static"]["orb"].update(min_nfm=-1.0), "must be a number >= 0"),
    (lambda m: m["test"]["agae"]["static"]["orb"].update(min_nfm=50.0), "min_nfm > median_nfm"),
    (lambda m: m["test"]["shin"].update(tracking_success=[3, 2]), "tracking_success"),
    (lambda m: m["test"]["shin"].update(tracking_success=[0, 0]), "tracking_success"),
])
def test_schema_names_what_is_wrong(breaker, fragment):
    m = _valid_metrics()
    breaker(m)
    problems = validate_metrics(m)
    assert any(fragment in p for p in problems), problems
