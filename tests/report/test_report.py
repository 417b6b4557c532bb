"""Report tables from a hand-made metrics.json / runs table, and clean errors on missing or malformed inputs."""

from __future__ import annotations

import copy
import json

import pandas as pd
import pytest

from expoctl.errors import ConfigError, InputError
from expoctl.evaluation.run import variants

VARIANTS = variants(("orb", "viso"))
from expoctl.report.results import (ReportConfig, headline, load_eval, nfm_table, runs_table, tracking_table,
                            vo_margin_table)


def _metrics():
    def entry(med, mn, ok):
        e = {k: {v: {"median_nfm": float(med), "min_nfm": float(mn)} for v in VARIANTS} for k in ("static", "dynamic")}
        e["tracking_success"] = [ok, 2]
        return e

    return {"validation": {"oracle": entry(500, 300, 2), "agae": entry(400, 50, 0), "learned": entry(420, 90, 2)}}


def test_nfm_table_orders_controllers_bolds_best_causal_and_italicises_the_oracle():
    md = nfm_table(_metrics(), "validation").splitlines()
    assert md[0].startswith("| Lighting | Method | Median NFM ORB")
    body = md[2:]
    assert [r.split("|")[2].strip() for r in body[:3]] == ["AG+AE", "Ours", "*Greedy oracle, one step*"]
    assert body[0].split("|")[3].strip() == "400"
    assert body[1].split("|")[3].strip() == "**420**" and body[1].split("|")[5].strip() == "**90**"
    assert body[2].split("|")[3].strip() == "*500*"  # the oracle is never bolded, even when highest
    assert "**Dynamic**" in body[3]
    sl = nfm_table(_metrics(), "validation", sumlog=True)
    assert "AG+AE (SL)" in sl


def test_nfm_table_has_the_offline_optimum_row_with_its_grid():
    bound = {"grid": {"label": "14-candidate ladder, 1 EV"}, "render_size": [640, 480],
             "metrics": {"validation": {"dynamic": {"orb": {"median_nfm": 610.0, "min_nfm": 333.4, "mean_nfm": 600.0},
                                                    "viso": {"median_nfm": 700.0, "min_nfm": 400.0,
                                                             "mean_nfm": 690.0}}}}}
    md = nfm_table(_metrics(), "validation", bound=bound).splitlines()
    # static has no bounded section: no row; dynamic: the bound's row after the controllers, in italics
    assert len(md) == 2 + 3 + 4
    assert md[-1] == ("| | *offline optimum (14-candidate ladder, 1 EV, 640×480)* | *610* | *700* | *333* | *400* |")
    sl = nfm_table(_metrics(), "validation", sumlog=True, bound=bound).splitlines()
    assert sl[-1] == "| | *offline optimum (14-candidate ladder, 1 EV, 640×480)* (SL) | — | — | — | — |"


def test_vo_margin_is_the_worst_pair_per_run_and_counts_runs_at_stricter_thresholds():
    runs = pd.DataFrame({"route_split": ["validation", "test", "validation", "test"],
                         "controller": ["agae", "agae", "learned", "learned"], "vo_min_inliers": [40, 90, 150, 20]})
    md = vo_margin_table(runs, thresholds=(20, 21, 100)).splitlines()
    assert md[0].count("tracked at ≥") == 3
    cells = {r.split("|")[1].strip(): [x.strip() for x in r.split("|")[2:-1]] for r in md[2:]}
    assert list(cells) == ["AG+AE", "Ours"]
    # a run fails below the threshold, so a worst pair of 20 still tracks at 20
    assert cells["AG+AE"] == ["40 / 40", "90 / 90", "2/2", "2/2", "0/2"]
    assert cells["Ours"] == ["150 / 150", "20 / 20", "2/2", "1/2", "1/2"]
    assert headline(_metrics(), runs)[0].endswith("(worst frame pair 150 vs 40 tracked inliers).")


def test_tracking_table_counts_and_ate_over_successes():
    runs = pd.DataFrame({"route_split": ["validation"] * 4, "controller": ["agae", "agae", "learned", "learned"],
                         "vo_success": [False, False, True, True], "vo_ate_m": [9.0, 9.0, 0.5, 1.5]})
    md = tracking_table(_metrics(), runs)
    assert "| AG+AE | 0/2 | — |" in md and "| Ours | 2/2 | 1.00 |" in md


def test_map_tracking_columns_enter_the_tables_and_the_headline():
    runs = pd.DataFrame({"route_split": ["validation"] * 4, "controller": ["agae", "agae", "learned", "learned"],
                         "sequence": ["w0", "w1", "w0", "w1"], "window_label": ["a", "b", "a", "b"],
                         "vo_success": [True] * 4, "vo_failed_at": [-1] * 4, "vo_ate_m": [0.5] * 4,
                         "vo_min_inliers": [80, 90, 200, 210],
                         "vo_map_success": [False, True, True, True], "vo_map_failed_at": [57, -1, -1, -1],
                         "vo_map_min_inliers": [12, 49, 120, 140]})
    md = tracking_table(_metrics(), runs)
    assert "map-tracking VO successes, validation" in md
    assert "| AG+AE | 0/2 | 1/2 | 0.50 |" in md and "| Ours | 2/2 | 2/2 | 0.50 |" in md
    per = runs_table(runs)
    assert "| w0 (a) | tracked / lost at 57 | tracked / tracked |" in per
    margin = vo_margin_table(runs, (30, 50), "vo_map_min_inliers").splitlines()
    cells = {r.split("|")[1].strip(): [x.strip() for x in r.split("|")[2:-1]] for r in margin[2:]}
    assert cells["AG+AE"] == ["12 / 30", "1/2", "0/2"] and cells["Ours"] == ["120 / 130", "2/2", "2/2"]
    assert headline(_metrics(), runs)[0].endswith("; map-tracking VO 2/2 vs 1/2.")


def test_load_eval_names_missing_and_malformed_files(tmp_path):
    with pytest.raises(InputError, match="metrics.json: missing"):
        load_eval(tmp_path)
    (tmp_path / "metrics.json").write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        load_eval(tmp_path)
    bad = copy.deepcopy(_metrics())
    del bad["validation"]["agae"]["dynamic"]["viso"]
    (tmp_path / "metrics.json").write_text(json.dumps(bad))
    with pytest.raises(InputError, match="schema"):
        load_eval(tmp_path)
    (tmp_path / "metrics.json").write_text(json.dumps(_metrics()))
    with pytest.raises(InputError, match="frames.parquet: missing"):
        load_eval(tmp_path)


def test_report_config_checks():
    assert ReportConfig.from_dict(None) == ReportConfig()
    with pytest.raises(ConfigError, match="report.strip_portal"):
        ReportConfig.from_dict({"strip_portal": "middle"})


def test_selection_section_names_the_chosen_network_and_its_statistics():
    from expoctl.report.results import selection_section

    def stats(name, vo, orb, viso, off, clip, score=None):
        return {"name": name, "vo_ok": vo, "vo_runs": 2, "dynamic_min_nfm": {"orb": orb, "viso": viso},
                "median_offset_ev": off, "median_saturated_frac": clip, "score": score}

    sel = {"chosen": "iteration1", "rule": "most windows with VO tracking, …", "city": "train", "reference": "agae",
           "windows": [{"sequence": "select-train-t300-w00"}, {"sequence": "select-train-t300-w01"}],
           "scores": [stats("iteration1", 2, 210.4, 300.0, 1.04, 0.02, 1.0),
                      stats("iteration2", 0, 0.0, None, 6.5, 1.0, 0.0)],
           "reference_statistics": {**stats("agae", 2, 120.0, 280.0, None, 0.0), "score": None}}
    md = "\n".join(selection_section(sel))
    assert "The final model is **iteration1**'s network" in md
    assert "select-train-t300-w00, select-train-t300-w01" in md
    assert "| **iteration1** | 2/2 | 210 | 300 | +1.0 | 2 % | 1.00 |" in md
    assert "| iteration2 | 0/2 | 0 | — | +6.5 | 100 % | 0.00 |" in md
    assert "| agae | 2/2 | 120 | 280 | — | 0 % | — |" in md
    # the disabled stage: one line, no table
    md = selection_section({"chosen": "iteration2", "rule": "select_model.enabled is false", "scores": []})
    assert md == ["## Which network was evaluated", "",
                  "The final model is **iteration2**'s network (select_model.enabled is false).", ""]
