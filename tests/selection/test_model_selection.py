"""expoctl.selection.model_selection: the config, the statistics and rule (exact, on hand-made tables), and a
closed-loop selection at fixture scale that must reject a network stuck in saturation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from eval_fixtures import selection_project, use_real_or_test_sensor

from expoctl.errors import ConfigError, InputError
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.selection.model_selection import (Candidate, SelectConfig, choose, run_statistics, score_candidates,
                                               select_model)

# ------------------------------------------------------------------------------------------------------------ config


def test_config_defaults_and_plan():
    c = SelectConfig.from_dict({})
    assert not c.enabled and c.city == "train" and c.reference == "agae"
    assert c.plan.first_traversal == 300 and c.plan.n_traversals == 1 and c.plan.window == "passage"
    c = SelectConfig.from_dict({"first_traversal": 5, "window": "portal", "windows": [1], "reference": None})
    assert (c.plan.first_traversal, c.plan.window, c.plan.windows, c.reference) == (5, "portal", (1,), None)


@pytest.mark.parametrize("d, key", [
    ({"city": "test"}, "select_model.city"),
    ({"city": ""}, "select_model.city"),
    ({"reference": "learned"}, "select_model.reference"),
    ({"reference": "oracle"}, "select_model.reference"),
    ({"enabled": "yes"}, "select_model.enabled"),
    ({"before_s": -1.0}, "select_model.before_s"),
    ({"n_traversals": 0}, "select_model.n_traversals"),
    ({"window": "lap"}, "select_model.window"),
    ({"traversals": 2}, "select_model.traversals"),
])
def test_bad_config_names_the_key(d, key):
    with pytest.raises(ConfigError) as e:
        SelectConfig.from_dict(d)
    assert e.value.key == key


def test_missing_section():
    with pytest.raises(ConfigError, match="select_model"):
        SelectConfig.from_dict(None)


# -------------------------------------------------------------------------------------------------- statistics, rule


def _stats(name, vo_ok, orb, viso, vo_runs=2):
    return {"name": name, "vo_ok": vo_ok, "vo_runs": vo_runs, "dynamic_min_nfm": {"orb": orb, "viso": viso}}


def _cands(n):
    return [Candidate(f"iteration{k}", k, Path(f"m{k}.pt")) for k in range(1, n + 1)]


def test_score_is_mean_ratio_to_best_per_front_end():
    s = score_candidates([_stats("a", 2, 100.0, 40.0), _stats("b", 2, 50.0, 80.0), _stats("c", 2, None, 20.0)])
    assert [x["score"] for x in s] == [pytest.approx(0.75), pytest.approx(0.75), pytest.approx(0.125)]
    # a front end nobody has a value for, or whose best is 0, counts 0 for every candidate
    s = score_candidates([_stats("a", 1, None, 0.0), _stats("b", 1, None, 0.0)])
    assert [x["score"] for x in s] == [0.0, 0.0]


def test_rule_vo_first_then_score_then_later_iteration():
    cands = _cands(3)
    # iteration 3 has the best minima but lost track once: VO decides
    scored = score_candidates([_stats("iteration1", 2, 90.0, 60.0), _stats("iteration2", 2, 80.0, 70.0),
                               _stats("iteration3", 1, 200.0, 100.0)])
    assert choose(cands, scored).name == "iteration2"
    # ratios to the best of all candidates (iteration 3's 200 and 100): (90/200 + 60/100)/2 < (80/200 + 70/100)/2
    assert scored[0]["score"] == pytest.approx(0.525) and scored[1]["score"] == pytest.approx(0.55)
    # exact tie on VO and score: the later iteration (the paper keeps the last)
    tied = score_candidates([_stats("iteration1", 2, 50.0, 50.0), _stats("iteration2", 2, 50.0, 50.0)])
    assert choose(cands[:2], tied).name == "iteration2"
    with pytest.raises(ValueError):
        choose(cands, tied)


def _frames(candidate, sequence, gain_db, exposure_us, saturated):
    return pd.DataFrame({"candidate": candidate, "sequence": sequence, "frame": np.arange(4), "gain_db": gain_db,
                         "exposure_us": exposure_us, "saturated_frac": saturated})


def test_run_statistics_exact():
    frames = pd.concat([
        _frames("iteration1", "w0", 6.0206, 2000.0, [0.0, 0.1, 0.2, 0.3]),  # +1 EV gain, +1 EV exposure: +2 EV
        _frames("agae", "w0", 0.0, 1000.0, 0.0),
    ])
    runs = pd.DataFrame({"run_id": ["w0-iteration1", "w0-agae"], "candidate": ["iteration1", "agae"],
                         "vo_success": [True, False]})
    sections = pd.DataFrame({
        "run_id": ["w0-iteration1"] * 3 + ["w0-agae"],
        "section": ["static", "dynamic", "dynamic", "dynamic"],
        "min_nfm_orb": [300.0, 100.0, 50.0, 10.0], "min_nfm_viso": [200.0, 40.0, 20.0, 5.0],
        "median_nfm_orb": [400.0, 150.0, 90.0, 20.0], "median_nfm_viso": [250.0, 60.0, 30.0, 9.0],
    })
    s = run_statistics(frames, runs, sections, "iteration1", reference="agae")
    assert (s["vo_ok"], s["vo_runs"]) == (1, 1)
    assert s["dynamic_min_nfm"] == {"orb": 75.0, "viso": 30.0}  # mean over its two dynamic sections
    assert s["static_median_nfm"] == {"orb": 400.0, "viso": 250.0}
    assert s["median_saturated_frac"] == pytest.approx(0.15)
    assert s["median_offset_ev"] == pytest.approx(2.0, abs=1e-4)
    ref = run_statistics(frames, runs, sections, "agae")
    assert ref["vo_ok"] == 0 and ref["dynamic_min_nfm"]["orb"] == 10.0 and "median_offset_ev" not in ref
    assert ref["static_median_nfm"] == {"orb": None, "viso": None}


# --------------------------------------------------------------------------------------------- closed loop, fixture


def _select(cfg, cands, root):
    """select_model as the stage calls it: on the typed configs built once from the resolved config."""
    return select_model(EvaluationInputs.from_resolved(cfg), SelectConfig.from_dict(cfg.get("select_model")), cands,
                        root)


@pytest.fixture(scope="module")
def selected(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    use_real_or_test_sensor(mp)
    root = tmp_path_factory.mktemp("select")
    cfg, cands = selection_project(root)
    yield cfg, cands, _select(cfg, cands, root), root
    mp.undo()


def test_selection_rejects_the_saturated_network(selected):
    cfg, cands, result, _ = selected
    assert result.chosen.name == "iteration1"
    good, white = result.scores
    assert white["median_saturated_frac"] == 1.0  # 30 ms at 30 dB clips every pixel
    assert good["median_saturated_frac"] < 0.5
    assert good["score"] == 1.0 and white["score"] < 0.1
    assert (good["vo_ok"], white["vo_ok"]) == (1, 0)
    assert good["dynamic_min_nfm"]["orb"] > 0 and white["dynamic_min_nfm"] == {"orb": 0.0, "viso": 0.0}
    # 30 ms · 10^(30/20) over 150 µs at 0 dB: log2(200) + 30/6.0206 EV
    assert white["median_offset_ev"] - good["median_offset_ev"] == pytest.approx(math.log2(200) + 30 / 6.0206,
                                                                               abs=1e-3)
    assert result.reference["name"] == "agae"


def test_selection_drives_the_training_city_only(selected):
    _, cands, result, _ = selected
    assert [w.city_name for w in result.windows] == ["train"]
    assert all(w.route_split == "select" and w.traversal == 300 for w in result.windows)
    assert set(result.runs["candidate"]) == {"iteration1", "iteration2", "agae"}
    assert set(result.frames["route_split"]) == {"select"}


def test_one_candidate_is_not_driven(tmp_path):
    cfg, cands = selection_project(tmp_path)
    result = _select(cfg, cands[:1], tmp_path)
    assert result.chosen.name == "iteration1" and result.scores == [] and result.runs.empty


def test_selection_traversals_must_not_be_evaluated_ones(tmp_path):
    cfg, cands = selection_project(tmp_path)
    cfg["select_model"] = {"city": "validation", "first_traversal": 0}  # evaluate drives validation traversal 0
    with pytest.raises(ConfigError) as e:
        _select(cfg, cands, tmp_path)
    assert e.value.key == "select_model.first_traversal" and "[0]" in str(e.value)


def test_missing_candidate_stops_before_driving(tmp_path):
    cfg, cands = selection_project(tmp_path)
    cands[1].path.unlink()
    with pytest.raises(InputError, match="white.pt: the iteration2 network is missing"):
        _select(cfg, cands, tmp_path)


def test_probe_filter_keeps_the_passing_candidates_in_order_or_all_when_none_pass():
    from expoctl.selection.model_selection import probe_filter

    cands = _cands(3)
    res = {c.name: {"passes": ok} for c, ok in zip(cands, (True, False, True))}
    assert probe_filter(cands, res) == [cands[0], cands[2]]
    assert probe_filter(cands, {c.name: {"passes": False} for c in cands}) == cands
