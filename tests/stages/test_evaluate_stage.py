"""The evaluate and report stages at fixture scale (real world renderer, every controller incl. learned + oracle)."""

from __future__ import annotations

import json

import pandas as pd
import pytest
from eval_fixtures import make_fixture_project, use_real_or_test_sensor

from expoctl.errors import InputError
from expoctl.evaluation.aggregate import validate_metrics
from expoctl.controllers.registry import controller_names

CONTROLLER_NAMES = controller_names()  # every registered controller
from fake_tracker import FakeTracker


@pytest.fixture(scope="module")
def evaluated(tmp_path_factory):
    mp = pytest.MonkeyPatch()
    use_real_or_test_sensor(mp)
    from stages import evaluate as stage

    root = tmp_path_factory.mktemp("proj")
    cfg = make_fixture_project(root)
    tracker = FakeTracker()
    stage.run(cfg, tracker, project_root=root)
    yield root, cfg, tracker
    mp.undo()


def test_metrics_json_follows_the_design_schema(evaluated):
    root, _, tracker = evaluated
    metrics = json.loads((root / "reports/metrics.json").read_text())
    assert validate_metrics(metrics) == []
    for split in ("validation", "test"):
        assert set(metrics[split]) == set(CONTROLLER_NAMES)
        for c in CONTROLLER_NAMES:
            assert metrics[split][c]["tracking_success"][1] == 1  # one window per split
            for kind in ("static", "dynamic"):
                assert metrics[split][c][kind]["orb"]["median_nfm"] is not None
    assert str(root / "reports/metrics.json") in tracker.artifacts
    assert tracker.metrics["n_runs"] == 14


def test_eval_tables(evaluated):
    root, _, _ = evaluated
    frames = pd.read_parquet(root / "reports/eval/frames.parquet")
    runs = pd.read_parquet(root / "reports/eval/runs.parquet")
    assert len(runs) == 14 and set(runs.controller) == set(CONTROLLER_NAMES)
    assert {"vo_success", "vo_failed_at", "vo_ate_m", "vo_map_success", "vo_map_failed_at",
            "vo_map_min_inliers"} <= set(runs.columns)
    # a run that kept its map kept every tracked frame at or above the map threshold (30), and a lost one names a frame
    ok = runs.vo_map_success.astype(bool)
    assert (runs.loc[ok, "vo_map_min_inliers"] >= 30).all() and (runs.loc[ok, "vo_map_failed_at"] == -1).all()
    assert (runs.loc[~ok, "vo_map_failed_at"] >= 8).all()  # never during the 8 bootstrap frames
    for col in ("gain_db", "exposure_us", "mean_grey", "saturated_frac", "nfm_orb", "nfm_viso", "nfm_orb_sumlog",
                "nfm_viso_sumlog", "vo_n_inliers", "vo_map_n_inliers", "section", "portal_dt_s"):
        assert col in frames.columns, col
    # every controller drove the same frames of the same windows
    per = frames.groupby(["sequence", "controller"])["traj_frame"].apply(tuple).unstack()
    assert all(per.nunique(axis=1) == 1)
    assert {"static", "dynamic"} <= set(frames.section) <= {"static", "dynamic", "interior"}  # interior: in a tunnel, off its portals
    # the fixed controller really held its manual setting; the oracle really searched
    fixed = frames[frames.controller == "fixed"]
    assert set(fixed.exposure_us) == {2000.0} and set(fixed.gain_db) == {0.0}
    # render once (default share_render false): per window (2 warm-up frames + n recorded + the oracle's look-ahead at
    # the window's stop) one noise field per frame serves all 7 runs; each (frame, exposure) is rendered once, so the
    # sharp renders are the window's renders: at least the oracle's 4 candidate exposures of every frame after the first
    for _, w in runs.groupby("sequence"):
        assert w.window_sharp_renders.nunique() == 1 and w.window_noise_draws.nunique() == 1
        n = int(w.n_frames.iloc[0])
        assert int(w.window_noise_draws.iloc[0]) == n + 3
        assert int(w.window_sharp_renders.iloc[0]) == int(w.window_renders.iloc[0]) >= 4 * (n + 2)
    assert json.loads((root / "reports/eval/sumlog.json").read_text())["orb"]["beta"] in (2.0, 8.0)


def test_report_stage_writes_tables_and_figures(evaluated):
    root, cfg, _ = evaluated
    from stages import report

    tracker = FakeTracker()
    report.run(cfg, tracker, project_root=root)
    md = (root / "reports/results.md").read_text()
    for heading in ("Table I", "Table II", "Table III", "Greedy oracle", "AG+AE", "Ours"):
        assert heading in md
    for fig in ("fig7_tunnel_timeline", "fig6_image_strips", "nfm_bars_test_dynamic"):
        assert (root / f"reports/figures/{fig}.png").stat().st_size > 5000
        assert f"figures/{fig}.png" in md
    headline = json.loads((root / "reports/headline.json").read_text())
    metrics = json.loads((root / "reports/metrics.json").read_text())
    assert headline["val_loss"] is None  # the fixture's network was never trained
    assert headline["dynamic_min_nfm"]["test"]["orb"]["learned"] == metrics["test"]["learned"]["dynamic"]["orb"]["min_nfm"]
    assert str(root / "reports/headline.json") in tracker.artifacts


def test_missing_model_fails_with_a_message(tmp_path, monkeypatch):
    from stages import evaluate as stage

    cfg = make_fixture_project(tmp_path, controllers=["agae", "learned"])
    (tmp_path / "models/controller.pt").unlink()
    with pytest.raises(InputError, match="controller.pt: trained model missing"):
        stage.run(cfg, FakeTracker(), project_root=tmp_path)
    assert not (tmp_path / "reports").exists()


def _no_evaluation(*args, **kwargs):
    raise AssertionError("evaluation work started before the network was checked")


@pytest.mark.parametrize("damage", ["truncated", "random", "shapes", "onnx_missing"])
def test_a_bad_final_model_stops_the_stage_before_any_evaluation(tmp_path, monkeypatch, damage):
    """Before: a truncated models/controller_final.pt failed only after the whole evaluation (18 s at fixture
    scale) with `[Errno 22] Invalid argument`. Now the stage checks the network first and names the file."""
    import torch

    from stages import evaluate as stage

    monkeypatch.setattr(stage, "evaluate", _no_evaluation)
    monkeypatch.setattr("expoctl.evaluation.runner.evaluate", _no_evaluation)
    cfg = make_fixture_project(tmp_path)
    final = tmp_path / "models/controller_final.pt"
    data = (tmp_path / "models/controller.pt").read_bytes()
    cfg["paths"]["final_model"] = "models/controller_final.pt"
    if damage == "truncated":
        final.write_bytes(data[: len(data) // 2])
        expected = f"{final}: truncated or not a PyTorch file ({len(data) // 2} bytes; the zip archive"
    elif damage == "random":
        final.write_bytes(bytes(range(256)) * 8)
        expected = f"{final}: truncated or not a PyTorch file (2048 bytes, not starting with the zip header"
    elif damage == "shapes":
        ckpt = torch.load(tmp_path / "models/controller.pt", weights_only=True)
        ckpt["model_config"]["fc_widths"] = [8, 8, 16]
        torch.save(ckpt, final)
        expected = (f"{final}: state_dict does not match model_config: head.9.weight has shape [8, 8], expected "
                    "[16, 8]")
    else:  # the onnx backend needs the .onnx beside the checkpoint
        final.write_bytes(data)
        cfg["controllers"]["learned"] = {"backend": "onnx"}
        expected = f"{final.with_suffix('.onnx')}: ONNX export missing"
    with pytest.raises(InputError) as e:
        stage.run(cfg, FakeTracker(), project_root=tmp_path)
    assert str(e.value).startswith(expected)
    assert not (tmp_path / "reports/metrics.json").exists()
