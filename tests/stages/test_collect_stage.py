"""The collect stage entry point: writes the raw dir named by paths.raw_dir and logs its metrics (fake tracker)."""

from __future__ import annotations

import yaml

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
                    "warmup_frames": 1, "sensor_randomisation": 0.1, "n_jobs": 1,
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
