"""The select_model stage: candidates from the iteration blocks, the chosen network copied to paths.final_model,
reports/select_model.json; enabled: false keeps the last iteration's network; a missing candidate stops cleanly."""

from __future__ import annotations

import json

import pytest
from eval_fixtures import selection_project, use_real_or_test_sensor

from expoctl.errors import InputError
from fake_tracker import FakeTracker


@pytest.fixture
def project(tmp_path, monkeypatch):
    use_real_or_test_sensor(monkeypatch)
    cfg, _ = selection_project(tmp_path)
    return tmp_path, cfg


def test_stage_copies_the_chosen_network(project):
    """The selection windows alone (probe off) reject the saturated network."""
    from stages import select_model as stage

    root, cfg = project
    cfg["select_model"]["probe"]["enabled"] = False
    tracker = FakeTracker()
    stage.run(cfg, tracker, project_root=root)
    models = root / "models"
    assert (models / "controller_final.pt").read_bytes() == (models / "good.pt").read_bytes()
    assert (models / "controller_final.onnx").read_bytes() == (models / "good.onnx").read_bytes()
    report = json.loads((root / "reports/select_model.json").read_text())
    assert report["chosen"] == "iteration1" and report["final_model"] == "models/controller_final.pt"
    assert [c["name"] for c in report["candidates"]] == ["iteration1", "iteration2"]  # iteration 3 is off
    assert [c["path"] for c in report["candidates"]] == ["models/good.pt", "models/white.pt"]
    assert {r["candidate"] for r in report["runs"]} == {"iteration1", "iteration2", "agae"}
    assert report["scores"][1]["median_saturated_frac"] == 1.0 and report["reference_statistics"]["name"] == "agae"
    assert tracker.metrics["chosen_iteration"] == 1 and tracker.params == {"chosen": "iteration1"}
    assert tracker.metrics["iteration2.vo_ok"] == 0 and tracker.metrics["iteration1.vo_ok"] == 1
    assert str(root / "reports/select_model.json") in tracker.artifacts


def test_disabled_keeps_the_last_iteration_without_driving(project):
    from stages import select_model as stage

    root, cfg = project
    cfg["select_model"]["enabled"] = False
    cfg["select_model"]["probe"]["enabled"] = False
    stage.run(cfg, FakeTracker(), project_root=root)
    assert (root / "models/controller_final.pt").read_bytes() == (root / "models/white.pt").read_bytes()
    report = json.loads((root / "reports/select_model.json").read_text())
    assert report["chosen"] == "iteration2" and report["scores"] == [] and report["runs"] == []
    assert report["probe"] is None and "enabled is false" in report["rule"]


def test_the_probe_drops_a_saturated_network_before_the_last_iteration_rule(project):
    """Windows off (the default): without the probe the paper's rule keeps iteration 2, which is stuck at 30 ms and
    30 dB; the probe ends every one of its starts with the whole frame clipped, so iteration 1 is the final model."""
    from stages import select_model as stage

    root, cfg = project
    cfg["select_model"]["enabled"] = False
    tracker = FakeTracker()
    stage.run(cfg, tracker, project_root=root)
    assert (root / "models/controller_final.pt").read_bytes() == (root / "models/good.pt").read_bytes()
    report = json.loads((root / "reports/select_model.json").read_text())
    probe = report["probe"]
    assert report["chosen"] == "iteration1" and probe["failed"] == ["iteration2"] and probe["kept"] == ["iteration1"]
    white, good = probe["results"]["iteration2"], probe["results"]["iteration1"]
    assert white["worst_saturated_frac"] == 1.0 and not white["passes"]
    assert all(r["final_saturated_frac"] == 1.0 for r in white["starts"]["open_road"])  # daylight at 30 ms, 30 dB
    assert good["passes"] and good["worst_saturated_frac"] < 0.5
    assert set(good["starts"]) == {"open_road", "tunnel"} and [r["k_ev"] for r in good["starts"]["tunnel"]] == [0, 6]
    assert "saturation probe" in report["rule"] and report["runs"] == []
    assert tracker.metrics["iteration2.probe_passes"] == 0 and tracker.metrics["iteration1.probe_passes"] == 1


def test_missing_onnx_stops_before_any_output(project):
    from stages import select_model as stage

    root, cfg = project
    (root / "models/white.onnx").unlink()
    with pytest.raises(InputError, match="white.onnx: the iteration2 network is missing"):
        stage.run(cfg, FakeTracker(), project_root=root)
    assert not (root / "models/controller_final.pt").exists()
    assert not (root / "reports/select_model.json").exists()


def test_bad_config_stops_before_any_output(project):
    from stages import select_model as stage

    root, cfg = project
    cfg["select_model"]["city"] = "test"
    with pytest.raises(InputError, match="select_model.city"):
        stage.run(cfg, FakeTracker(), project_root=root)
    assert not (root / "models/controller_final.pt").exists()


def test_every_candidate_failing_the_probe_is_said_and_recorded(project, caplog):
    """Both iterations' networks stuck at 30 ms and 30 dB: the probe fails both, keeps both, and the last one is the
    final model — with a WARNING and the reason in reports/select_model.json (before: picked without a word)."""
    from stages import select_model as stage

    root, cfg = project
    cfg["paths"]["model"] = "models/white.pt"  # iteration 1 as saturated as iteration 2
    cfg["select_model"]["enabled"] = False
    tracker = FakeTracker()
    with caplog.at_level("WARNING"):
        stage.run(cfg, tracker, project_root=root)
    report = json.loads((root / "reports/select_model.json").read_text())
    assert report["chosen"] == "iteration2" and report["probe"]["failed"] == ["iteration1", "iteration2"]
    assert report["chosen_failed_probe"] is True
    note = ("the final model iteration2 FAILED the saturation probe (worst start ends 100 % clipped white, at least "
            "select_model.probe.max_saturated_fraction 0.97) but was still chosen: every candidate failed the probe "
            "(iteration1, iteration2), so it could exclude none and all were kept; select_model.enabled is false, so "
            "the last remaining iteration's network was kept. It may run the camera into saturation: check "
            "reports/select_model.json's probe results before trusting the evaluation")
    assert report["note"] == note
    assert [r.getMessage() for r in caplog.records if r.levelname == "WARNING"] == [note]
    assert tracker.metrics["chosen_failed_probe"] == 1


def test_a_chosen_network_that_passed_has_no_note(project):
    from stages import select_model as stage

    root, cfg = project
    cfg["select_model"]["enabled"] = False
    tracker = FakeTracker()
    stage.run(cfg, tracker, project_root=root)
    report = json.loads((root / "reports/select_model.json").read_text())
    assert report["chosen"] == "iteration1"
    assert report["chosen_failed_probe"] is False and report["note"] is None
    assert tracker.metrics["chosen_failed_probe"] == 0


def _no_work(*args, **kwargs):
    raise AssertionError("selection work started before the candidates were checked")


def test_bad_candidate_checkpoints_stop_before_any_probe(project, monkeypatch):
    """A truncated iteration-1 checkpoint and an iteration-2 .onnx of random bytes: one InputError naming both
    files, before the probe or the selection windows run and before any output."""
    from stages import select_model as stage

    root, cfg = project
    monkeypatch.setattr(stage, "probe_candidates", _no_work)
    monkeypatch.setattr(stage, "select_model", _no_work)
    good, white = root / "models/good.pt", root / "models/white.onnx"
    data = good.read_bytes()
    good.write_bytes(data[: len(data) // 2])
    white.write_bytes(b"\x01\x02" * 500)
    with pytest.raises(InputError) as e:
        stage.run(cfg, FakeTracker(), project_root=root)
    first, second = str(e.value).split("\n")
    assert first == (f"{good}: truncated or not a PyTorch file ({len(data) // 2} bytes; the zip archive torch.save "
                     "writes has no end record: [Errno 22] Invalid argument) (the iteration1 network)")
    assert second.startswith(f"{white}: not loadable by onnxruntime: truncated or not an ONNX model (1000 bytes; ")
    assert second.endswith("(the iteration2 network)")
    assert not (root / "models/controller_final.pt").exists()
    assert not (root / "reports/select_model.json").exists()


def test_candidate_whose_weights_do_not_fit_its_model_config(project, monkeypatch):
    import torch

    from stages import select_model as stage

    root, cfg = project
    monkeypatch.setattr(stage, "probe_candidates", _no_work)
    monkeypatch.setattr(stage, "select_model", _no_work)
    path = root / "models/white.pt"
    ckpt = torch.load(path, weights_only=True)
    ckpt["state_dict"]["head.9.weight"] = torch.zeros(8, 4)
    torch.save(ckpt, path)
    with pytest.raises(InputError, match=f"^{path}: state_dict does not match model_config: head.9.weight has shape "
                                         r"\[8, 4\], expected \[8, 8\] \(the iteration2 network\)$"):
        stage.run(cfg, FakeTracker(), project_root=root)
