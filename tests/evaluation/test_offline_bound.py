"""The offline bound (expoctl.evaluation.offline_bound): its dynamic programmes against brute force, and on a tiny closed
loop every built-in causal controller restricted to the grid scores at or below it, while the bound's own path,
driven as a controller through evaluate's loop, attains it exactly."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from eval_fixtures import moving_scene

from expoctl.camera.sensor import Sensor, SensorConfig
from expoctl.controllers.base import Settings
from expoctl.controllers.registry import ControllerContext, controller_names, make_controller, needs
from expoctl.evaluation.aggregate import section_stats
from expoctl.evaluation.run import WindowFrames, drive_window
from expoctl.features.orb import OrbFrontEnd
from expoctl.features.sumlog import SumLogParams
from expoctl.features.viso.frontend import VisoFrontEnd
from expoctl.evaluation.offline_bound import (GridController, OfflineBoundParams, ScheduleController, best_path, grid_label,
                                       kth_largest_bound, offline_bound, pair_matrices, path_values, section_bound,
                                       snap, window_sections)
from expoctl.sim.oracle import CachedScene, OracleParams


# ------------------------------------------------------------------------------------------------ the DPs, exact


def _all_paths(P: int, K: int):
    return itertools.product(range(K), repeat=P + 1)


@pytest.mark.parametrize("seed", range(6))
def test_dp_equals_brute_force(seed):
    rng = np.random.default_rng(seed)
    P, K = 4 + seed % 2, 3  # 4 or 5 edges (even and odd median), 3 states: 243 / 729 paths
    w = rng.integers(0, 9, size=(P, K, K)).astype(float)  # small integers: many ties
    vals = [path_values(w, p) for p in _all_paths(P, K)]
    vmin, pmin = best_path(w, "min")
    vsum, psum = best_path(w, "sum")
    assert vmin == max(v.min() for v in vals) and path_values(w, pmin).min() == vmin
    assert vsum == max(v.sum() for v in vals) and path_values(w, psum).sum() == vsum
    for k in range(1, P + 1):
        best_k = max(np.sort(v)[::-1][k - 1] for v in vals)
        vk, pk = kth_largest_bound(w, k)
        assert vk == best_k and np.sort(path_values(w, pk))[::-1][k - 1] == best_k
    b = section_bound(w)
    best_median = max(float(np.median(v)) for v in vals)
    assert b["median"]["value"] >= best_median  # an upper bound always
    assert b["median"]["attained"] == float(np.median(path_values(w, b["median"]["path"])))
    assert b["median"]["attained"] <= best_median
    if P % 2:  # odd: exact and attained
        assert b["median"]["value"] == best_median == b["median"]["attained"] and b["median"]["exact"]


def test_median_bound_even_case_not_always_attained():
    # two edges, two states: a path is (s0, s1, s2). Edge 0 is 10 only from state 0 to state 0, edge 1 is 10 only
    # from state 1 to state 1: no path has both, so the best median (5) is below the order-statistic bound (10)
    w = np.zeros((2, 2, 2))
    w[0, 0, 0] = 10.0
    w[1, 1, 1] = 10.0
    b = section_bound(w)
    assert b["median"]["value"] == 5.0  # (best largest 10 + best 2nd largest 0) / 2
    assert b["median"]["attained"] == 5.0 and b["median"]["exact"]
    w[1, 0, 1] = 4.0  # now (0, 0, 1) has 10 and 4: median 7; bound (10 + 4) / 2 = 7
    assert section_bound(w)["median"]["value"] == 7.0 == section_bound(w)["median"]["attained"]


def test_sections_follow_evaluate():
    labels = ["static"] * 3 + ["dynamic"] * 4 + ["static"] * 2
    assert window_sections(labels) == [
        {"section_id": 0, "kind": "static", "first_frame": 0, "last_frame": 2, "pairs": [1, 2]},
        {"section_id": 1, "kind": "dynamic", "first_frame": 3, "last_frame": 6, "pairs": [3, 4, 5, 6]},
        {"section_id": 2, "kind": "static", "first_frame": 7, "last_frame": 8, "pairs": [7, 8]}]
    assert [s["section_id"] for s in window_sections(labels, min_section_frames=3)] == [1]


def test_snap_and_grid_label():
    ladder = OracleParams().candidates()
    assert grid_label(ladder) == "14-candidate ladder, 1 EV"
    assert snap(Settings(0.0, 3000.0), ladder) == Settings(0.0, 3750.0)  # 0.32 EV below vs 0.68 EV above
    assert snap(Settings(12.0, 1000.0), ladder) == Settings(0.0, 3750.0)  # the same signal at 0 dB (+0.09 EV)
    assert snap(Settings(30.0, 30000.0), ladder) == Settings(30.0, 30000.0)


def test_config_needs_both_grid_keys():
    from expoctl.errors import ConfigError

    with pytest.raises(ConfigError, match="evaluate.offline_bound.gains_db"):
        OfflineBoundParams.from_dict({"exposures_us": [1000.0]})
    with pytest.raises(ConfigError, match="evaluate.offline_bound.enabled"):
        OfflineBoundParams.from_dict({"enabled": "yes please"})
    own = OfflineBoundParams.from_dict({"exposures_us": [4000.0, 1000.0], "gains_db": [12.0]})
    assert own.candidates() == [Settings(0.0, 4000.0), Settings(0.0, 1000.0), Settings(12.0, 4000.0)]
    assert OfflineBoundParams.from_dict(None).candidates() == OracleParams().candidates()


# ------------------------------------------------------------------------------------- the bound on a closed loop

W, H, N, START, WARMUP, SEED = 160, 120, 14, 4, 3, 11
SUMLOG = {"orb": SumLogParams(beta=4.0), "viso": SumLogParams(alpha=(0.0, 1.0, 0.0), beta=2.0)}
VARIANTS = ("orb", "viso", "orb_sumlog", "viso_sumlog")
GRID = OracleParams(exposures_us=(8000.0, 2000.0, 500.0, 125.0), gains_db=(12.0,)).candidates()  # 5 candidates


def _level(t: int) -> float:  # open road, then into a tunnel 5 EV darker over three frames
    return 2000.0 if t < START + 6 else (500.0 if t == START + 6 else (150.0 if t == START + 7 else 60.0))


@pytest.fixture(scope="module")
def rig():
    scene = CachedScene(moving_scene(_level, W, H, step_px=2), keep_frames=3)
    sensor = Sensor(SensorConfig(), H, W, seed=5).remember_noise()
    labels = ["static"] * 6 + ["dynamic"] * (N - 6)
    window = WindowFrames("tiny-w00", range(START, START + N), labels, [np.nan] * N, [""] * N, None)
    frontends = {"orb": OrbFrontEnd({"working_size": None, "count_nfeatures": 400, "match_nfeatures": 300}),
                 "viso": VisoFrontEnd()}
    bound = offline_bound(scene, sensor, window, SEED, frontends, candidates=GRID, sumlog=SUMLOG,
                          min_section_frames=3)
    mats = pair_matrices(scene, sensor, window, SEED, frontends, GRID, SUMLOG)
    return scene, sensor, window, frontends, bound, mats


def _drive(rig, controller):
    """evaluate's loop and NFM rule (WindowRun via drive_window) over the tiny window; its section statistics."""
    scene, sensor, window, _frontends, _bound, _mats = rig
    frontends = {"orb": OrbFrontEnd({"working_size": None, "count_nfeatures": 400, "match_nfeatures": 300}),
                 "viso": VisoFrontEnd()}  # fresh per run, as evaluate makes them
    K = np.array([[100.0, 0, W / 2], [0, 100.0, H / 2], [0, 0, 1]])
    rows, _summary, _thumbs = drive_window(scene, sensor, controller, window, seed=SEED, frontends=frontends,
                                           sumlog=SUMLOG, initial=Settings(0.0, 5000.0), warmup_frames=WARMUP, K=K,
                                           vo_min_inliers=8, vo_n_features=300)
    frames = pd.DataFrame(rows).assign(run_id="r", route_split="validation", controller="c")
    return frames, section_stats(frames, 3).set_index("section_id")


def _path_of(frames: pd.DataFrame) -> list[int]:
    return [GRID.index(Settings(g, e)) for g, e in zip(frames["gain_db"], frames["exposure_us"])]


def _grid_controllers(rig):
    scene, sensor, window = rig[0], rig[1], rig[2]
    names = [n for n in controller_names() if set(needs(n)) <= {"scene"}]  # learned needs a trained checkpoint
    assert {"agae", "shin", "shim", "mean_intensity", "fixed", "oracle"} <= set(names)
    context = ControllerContext(seed=SEED, scene=scene, sensor=sensor, n_frames=START + N,
                                first_frame=START - WARMUP)
    return [(n, GridController(make_controller(n, None, context), GRID)) for n in names]


def test_grid_controllers_score_at_or_below_the_bound(rig):
    _scene, _sensor, _window, _fes, bound, mats = rig
    assert [(s["section_id"], s["kind"], s["n_pairs"]) for s in bound.sections] == [(0, "static", 5),
                                                                                    (1, "dynamic", 8)]
    for name, ctrl in _grid_controllers(rig):
        frames, stats = _drive(rig, ctrl)
        path = _path_of(frames)  # every recorded frame is on the grid
        for v in VARIANTS:
            nfm = frames[f"nfm_{v}"].to_numpy()
            # the front ends' matchers keep no state: evaluate's NFM is the matrix entry of the controller's path
            assert [nfm[k] for k in range(1, N)] == [mats[v][k, path[k - 1], path[k]] for k in range(1, N)], name
            for s in bound.sections:
                b = s["bounds"][v]
                got = stats.loc[s["section_id"]]
                pairs = nfm[s["first_frame"] if s["first_frame"] else 1:s["last_frame"] + 1]
                assert got[f"min_nfm_{v}"] <= b["min"]["value"], (name, v, s["section_id"])
                assert pairs.sum() <= b["sum"]["value"], (name, v, s["section_id"])
                assert got[f"median_nfm_{v}"] <= b["median"]["value"], (name, v, s["section_id"])


@pytest.mark.parametrize("stat", ["min", "sum", "median"])
def test_the_bound_is_attained_by_its_path(rig, stat):
    _scene, _sensor, window, _fes, bound, _mats = rig
    for s in bound.sections:
        for v in VARIANTS:
            schedule = {window.frames.start + k: c for k, c in bound.path_settings(s["section_id"], v, stat).items()}
            frames, stats = _drive(rig, ScheduleController(schedule, START - WARMUP))
            got = stats.loc[s["section_id"]]
            b = s["bounds"][v][stat]
            if stat == "min":
                assert got[f"min_nfm_{v}"] == b["value"]
            elif stat == "sum":
                nfm = frames[f"nfm_{v}"].to_numpy()
                assert nfm[s["path_first_frame"] + 1:s["last_frame"] + 1].sum() == b["value"]
            else:
                assert got[f"median_nfm_{v}"] == b["attained"]
                assert b["exact"] == (b["attained"] == b["value"])


def test_the_bound_is_not_trivial(rig):
    # the dynamic section's bound beats the best fixed rung (no single exposure suits road and tunnel) on ORB's minimum
    bound, mats = rig[4], rig[5]
    dyn = bound.sections[1]
    ks = range(dyn["path_first_frame"] + 1, dyn["last_frame"] + 1)
    best_fixed = max(min(mats["orb"][k, c, c] for k in ks) for c in range(len(GRID)))
    assert dyn["bounds"]["orb"]["min"]["value"] > best_fixed


# ---------------------------------------------------------------------------------------- the evaluate stage's opt-in


def test_evaluate_stage_writes_the_bound_and_the_report_row(tmp_path, monkeypatch):
    import json

    from eval_fixtures import make_fixture_project, use_real_or_test_sensor
    from fake_tracker import FakeTracker

    from expoctl.report.results import build_report
    from stages import evaluate as stage

    use_real_or_test_sensor(monkeypatch)
    cfg = make_fixture_project(tmp_path, controllers=["fixed"])  # fixed: 0 dB, 2000 µs, a rung of the grid below
    cfg["evaluate"]["offline_bound"] = {"enabled": True, "exposures_us": [8000.0, 2000.0, 500.0], "gains_db": []}
    tracker = FakeTracker()
    stage.run(cfg, tracker, project_root=tmp_path)
    bound = json.loads((tmp_path / "reports/eval/offline_bound.json").read_text())
    metrics = json.loads((tmp_path / "reports/metrics.json").read_text())
    assert bound["grid"]["label"] == "3-candidate ladder, 2 EV" and bound["render_size"] == [96, 72]
    assert bound["grid"]["source"] == "evaluate.offline_bound"
    assert [w["sequence"] for w in bound["windows"]] == ["validation-validation-t000-w01", "test-test-t000-w01"]
    n = 0
    for split in ("validation", "test"):
        for kind, per in bound["metrics"][split].items():
            if kind not in metrics[split]["fixed"]:
                continue  # interior sections: in sections.parquet, not in metrics.json
            for v in ("orb", "viso"):
                fixed = metrics[split]["fixed"][kind][v]
                assert fixed["min_nfm"] <= per[v]["min_nfm"] and fixed["median_nfm"] <= per[v]["median_nfm"]
                n += 1
    assert n >= 4
    assert tracker.metrics["offline_bound.validation.dynamic.orb.min_nfm"] == \
        bound["metrics"]["validation"]["dynamic"]["orb"]["min_nfm"]
    build_report(tmp_path / "reports")
    assert "*offline optimum (3-candidate ladder, 2 EV, 96×72)*" in (tmp_path / "reports/results.md").read_text()


def test_evaluate_outputs_unchanged_when_the_bound_is_off(tmp_path, monkeypatch):
    from eval_fixtures import make_fixture_project, use_real_or_test_sensor
    from fake_tracker import FakeTracker

    from stages import evaluate as stage

    use_real_or_test_sensor(monkeypatch)
    cfg = make_fixture_project(tmp_path, controllers=["fixed"])
    stage.run(cfg, FakeTracker(), project_root=tmp_path)
    assert not (tmp_path / "reports/eval/offline_bound.json").exists()
    assert sorted(p.name for p in (tmp_path / "reports/eval").iterdir()) == [
        "frames.parquet", "runs.parquet", "sections.parquet", "sumlog.json", "thumbs", "windows.json"]
