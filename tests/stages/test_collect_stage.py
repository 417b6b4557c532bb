"""The collect stage entry point: writes the raw dir named by paths.raw_dir and logs its metrics (fake tracker)."""

from __future__ import annotations

import pytest
import yaml
from eval_fixtures import selection_project, use_real_or_test_sensor

from expoctl.raw.validate import validate_raw_dir
from stages import collect as stage
from fake_tracker import FakeTracker


def test_stage_writes_raw_dir_and_logs(tmp_path, caplog):
    (tmp_path / "cities").mkdir()
    (tmp_path / "cities" / "small.yaml").write_text(
        yaml.safe_dump({"base": "train", "name": "small", "textures": {"tile_px": 256}}))
    cfg = {
        "seed": 0,
        "paths": {"raw_dir": str(tmp_path / "raw")},
        "rig": {},
        "world": {"cities": {"train": "small"}, "city_dir": str(tmp_path / "cities"),
                  "render": {"width": 48, "height": 32}},
        "collect": {"reference_controller": "agae", "initial_gain_db": 0.0, "initial_exposure_us": 5000.0,
                    "warmup_frames": 1, "sensor_randomisation": 0.1,
                    "splits": {"train": {"n_sequences": 1, "frames": 3}, "validation": None, "test": None}},
    }
    tracker = FakeTracker()
    with caplog.at_level("INFO"):
        stage.run(cfg, tracker)
    assert any("1/1 train-small-t000: 3 frame pairs" in r.getMessage() for r in caplog.records)
    assert validate_raw_dir(tmp_path / "raw") == []
    assert (tmp_path / "raw" / "train" / "train-small-t000" / "cam2" / "000002.png").is_file()
    assert tracker.metrics["n_sequences"] == 1 and tracker.metrics["n_frame_pairs"] == 3
    assert tracker.metrics["n_sequences_train"] == 1 and tracker.metrics["n_sequences_test"] == 0


@pytest.mark.parametrize("network,passes", [("white", False), ("good", True)])
def test_iteration2_reference_gate_keeps_a_saturating_network_off_camera_1(tmp_path, monkeypatch, network, passes):
    """reference_gate: probe. The network stuck at 30 ms and 30 dB fails the saturation probe (the whole daylight
    frame clipped), so AG+AE drives camera 1 and the recording never reaches those settings; the constant 150 µs,
    0 dB network passes and drives camera 1 itself, so every recorded camera-1 frame after the first (the initial
    settings, the command landing one frame later) is at 150 µs. The decision is recorded beside the reports."""
    import json

    import pandas as pd

    from stages.iterations import for_iteration

    use_real_or_test_sensor(monkeypatch)
    cfg, _ = selection_project(tmp_path)
    cfg["paths"].update(model=str(tmp_path / "models" / f"{network}.pt"), raw_dir=str(tmp_path / "raw"),
                        reports_dir=str(tmp_path / "reports"))
    cfg["collect"] = {"reference_controller": "agae", "initial_gain_db": 0.0, "initial_exposure_us": 5000.0,
                      "warmup_frames": 0, "sensor_randomisation": 0.0,
                      "splits": {"train": {"n_sequences": 1, "frames": 4}, "validation": None, "test": None}}
    cfg["iteration2"] = {"enabled": True, "reference_gate": "probe", "collect": {"reference_controller": "learned"},
                         "paths": {"raw_dir": str(tmp_path / "raw2"), "reports_dir": str(tmp_path / "reports2")}}
    tracker = FakeTracker()
    stage.run(for_iteration(cfg, 2), tracker)
    decision = json.loads((tmp_path / "reports2" / "collect_reference.json").read_text())
    assert decision["probe"]["passes"] is passes and decision["network"] == "iteration1"
    assert decision["reference_controller"] == ("learned" if passes else "agae")
    assert tracker.params["reference_controller"] == decision["reference_controller"]
    assert tracker.metrics["reference_probe_passes"] == int(passes)
    assert validate_raw_dir(tmp_path / "raw2") == []
    (seq,) = (tmp_path / "raw2" / "train").iterdir()
    cam1 = pd.read_csv(seq / "frames.csv").query("camera == 1")
    if passes:
        assert cam1["exposure_us"].iloc[1:].tolist() == pytest.approx([150.0] * 3, rel=1e-6)
        assert cam1["gain_db"].iloc[1:].tolist() == pytest.approx([0.0] * 3, abs=1e-6)
    else:
        assert (cam1["exposure_us"] < 30000.0).all()


def test_reference_gate_none_is_the_papers_protocol_and_a_bad_gate_names_the_key(tmp_path, monkeypatch):
    """none: the network drives camera 1 without a probe; an unknown gate stops before any work with its key."""
    from expoctl.errors import ConfigError
    from stages.iterations import for_iteration

    use_real_or_test_sensor(monkeypatch)
    cfg, _ = selection_project(tmp_path)
    cfg["paths"].update(model=str(tmp_path / "models" / "white.pt"), raw_dir=str(tmp_path / "raw"))
    cfg["collect"] = {"reference_controller": "agae", "splits": {"train": None, "validation": None, "test": None}}
    block = {"enabled": True, "reference_gate": "none", "collect": {"reference_controller": "learned"},
             "paths": {"raw_dir": str(tmp_path / "raw2"), "reports_dir": str(tmp_path / "reports2")}}
    gated, decision = stage.gate_reference(stage.later_iteration_config(for_iteration({**cfg, "iteration2": block}, 2)))
    assert decision["probe"] is None and gated["collect"]["reference_controller"] == "learned"
    with pytest.raises(ConfigError) as exc:
        stage.later_iteration_config(for_iteration({**cfg, "iteration2": {**block, "reference_gate": "maybe"}}, 2))
    assert exc.value.key == "iteration2.reference_gate"
    assert not (tmp_path / "raw2").exists()


def test_reference_gate_reports_probe_and_collect_problems_in_one_pass(tmp_path, monkeypatch):
    """A bad select_model.probe value and a bad collect value are named together, before the probe drives a frame."""
    from expoctl.errors import ConfigError
    from stages.iterations import for_iteration

    use_real_or_test_sensor(monkeypatch)
    cfg, _ = selection_project(tmp_path)
    cfg["paths"].update(model=str(tmp_path / "models" / "white.pt"), raw_dir=str(tmp_path / "raw"))
    cfg["collect"] = {"reference_controller": "agae", "warmup_frames": -1,
                      "splits": {"train": None, "validation": None, "test": None}}
    cfg["select_model"] = {**cfg.get("select_model", {}), "probe": {"frames": 0}}
    block = {"enabled": True, "reference_gate": "probe", "collect": {"reference_controller": "learned"},
             "paths": {"raw_dir": str(tmp_path / "raw2"), "reports_dir": str(tmp_path / "reports2")}}
    with pytest.raises(ConfigError) as exc:
        stage.gate_reference(stage.later_iteration_config(for_iteration({**cfg, "iteration2": block}, 2)))
    keys = [k for k, _ in exc.value.problems]
    assert "select_model.probe.frames" in keys and "collect.warmup_frames" in keys, keys
    assert not (tmp_path / "reports2").exists()


def _no_work(*args, **kwargs):
    raise AssertionError("collect work started before the reference network was checked")


@pytest.mark.parametrize("backend", ["torch", "onnx"])
def test_a_bad_reference_network_stops_a_later_iteration_first(tmp_path, monkeypatch, backend):
    """Iteration 2 with the iteration-1 network as camera 1's reference: a truncated checkpoint (torch) or, with the
    onnx backend, a missing .onnx is one InputError naming the file, before the gate's probe or any recording."""
    from expoctl.errors import InputError
    from stages.iterations import for_iteration

    use_real_or_test_sensor(monkeypatch)
    monkeypatch.setattr(stage, "collect", _no_work)
    monkeypatch.setattr("expoctl.selection.saturation_probe.make_probe", _no_work)
    cfg, _ = selection_project(tmp_path)
    net = tmp_path / "models" / "good.pt"
    if backend == "torch":
        data = net.read_bytes()
        net.write_bytes(data[:4000])
        expected = f"{net}: truncated or not a PyTorch file (4000 bytes; the zip archive"
    else:
        net.with_suffix(".onnx").unlink()
        cfg["controllers"]["learned"] = {"backend": "onnx"}
        expected = f"{net.with_suffix('.onnx')}: ONNX export missing"
    cfg["paths"].update(model=str(net), raw_dir=str(tmp_path / "raw"))
    cfg["collect"] = {"reference_controller": "agae", "initial_gain_db": 0.0, "initial_exposure_us": 5000.0,
                      "warmup_frames": 0, "sensor_randomisation": 0.0,
                      "splits": {"train": {"n_sequences": 1, "frames": 4}, "validation": None, "test": None}}
    cfg["iteration2"] = {"enabled": True, "reference_gate": "probe", "collect": {"reference_controller": "learned"},
                         "paths": {"raw_dir": str(tmp_path / "raw2"), "reports_dir": str(tmp_path / "reports2")}}
    with pytest.raises(InputError) as e:
        stage.run(for_iteration(cfg, 2), FakeTracker())
    assert str(e.value).startswith(expected)
    assert not (tmp_path / "raw2").exists() and not (tmp_path / "reports2").exists()
    # a disabled iteration records nothing, so its reference network is not read at all
    cfg["iteration2"]["enabled"] = False
    monkeypatch.setattr(stage, "collect", lambda *a, **k: [])
    stage.run(for_iteration(cfg, 2), FakeTracker())
