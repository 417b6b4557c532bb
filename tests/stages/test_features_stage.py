"""The features stage's run(cfg, tracker) on a tiny generated project, with a fake tracker."""

import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

from expoctl.errors import ConfigError, InputError
from expoctl.parallel import MOVED_N_JOBS

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "features"))
from test_pipeline import make_project  # noqa: E402  (the generated panning sequences of the pipeline tests)

from stages import features as stage  # noqa: E402
from fake_tracker import FakeTracker  # noqa: E402

CONF = Path(__file__).resolve().parents[2] / "conf" / "features" / "default.yaml"


def _cfg(features):
    return {"features": features, "paths": {"frames": "data/frames.parquet", "features": "data/features.parquet",
                                            "matches": "data/matches.parquet"}}


def test_run_writes_both_tables_and_logs(tmp_path):
    frames = make_project(tmp_path, n_frames=3, sequences=("seq_a",))
    frames.to_parquet(tmp_path / "data/frames.parquet")
    features_cfg = yaml.safe_load(CONF.read_text())  # the shipped defaults, only made small
    features_cfg.update(frontends=["orb"])
    features_cfg["orb"].update(working_size=None, count_nfeatures=300, match_nfeatures=150)
    tracker = FakeTracker()
    stage.run(_cfg(features_cfg), tracker, project_root=tmp_path)
    feats = pd.read_parquet(tmp_path / "data/features.parquet")
    matches = pd.read_parquet(tmp_path / "data/matches.parquet")
    assert len(feats) == 6 and len(matches) == 8
    assert tracker.metrics["n_images"] == 6 and tracker.metrics["n_pairs"] == 8
    assert tracker.metrics["images_per_s"] > 0
    assert tracker.metrics["orb.median_n_features"] == feats.n_features.median()
    assert tracker.params["effective"]["orb"]["match_nfeatures"] == 150


def test_missing_frames_table_is_an_input_error_and_writes_nothing(tmp_path):
    with pytest.raises(InputError, match="frames table missing"):
        stage.run(_cfg({"frontends": ["orb"]}), FakeTracker(), project_root=tmp_path)
    assert not (tmp_path / "data/features.parquet").exists()


def test_bad_config_fails_before_reading(tmp_path):
    with pytest.raises(ConfigError, match="features.seed"):
        stage.run(_cfg({"seed": "two"}), FakeTracker(), project_root=tmp_path)


def test_the_old_worker_count_key_names_where_it_moved(tmp_path):
    """features.n_jobs became parallel.n_jobs (2026-12-07): a config that still sets it is told where it went."""
    with pytest.raises(ConfigError) as exc:
        stage.run(_cfg({"n_jobs": 2}), FakeTracker(), project_root=tmp_path)
    assert exc.value.problems == [("features.n_jobs", f"moved to parallel.n_jobs ({MOVED_N_JOBS})")]


def test_bad_image_leaves_previous_outputs_untouched(tmp_path):
    frames = make_project(tmp_path, n_frames=2, sequences=("seq_a",))
    frames.to_parquet(tmp_path / "data/frames.parquet")
    (tmp_path / "data/features.parquet").write_bytes(b"previous")
    (tmp_path / "data/raw/seq_a/cam1/000001.png").write_bytes(b"")
    with pytest.raises(InputError, match="000001.png"):
        stage.run(_cfg({"frontends": ["orb"], "orb": {"working_size": None}}), FakeTracker(),
                  project_root=tmp_path)
    assert (tmp_path / "data/features.parquet").read_bytes() == b"previous"
    assert not (tmp_path / "data/matches.parquet").exists()
