"""End to end: the whole DAG at fixture scale in a throw-away copy of the project."""

from __future__ import annotations

import re

import pandas as pd
import pytest
from synthetic_raw import write_synthetic_sequence

pytestmark = pytest.mark.slow


def _ran(output: str) -> set[str]:
    return set(re.findall(r"Running stage '([\w-]+)'", output))


def test_repro_noop_and_per_key_rerun(project_copy):
    p = project_copy
    all_stages = {"compose", "collect", "ingest", "features", "labels", "samples", "train"}

    first = p.dvc("repro")
    assert _ran(first.stdout) == all_stages, first.stdout
    frames = pd.read_parquet(p.root / "data" / "frames.parquet")
    assert {"sequence", "frame_id", "camera", "timestamp_ns", "gain_db", "exposure_us", "image_path", "split",
            "section"} <= set(frames.columns)
    assert len(frames) == 4 * 12 * 2  # fixture: 2 train + 1 validation + 1 test sequences of 12 frame pairs
    assert set(frames["split"]) == {"train", "validation", "test"} and "dynamic" in set(frames["section"])
    for out in ("data/features.parquet", "data/matches.parquet", "data/labels.parquet", "data/samples.parquet",
                "models/controller.pt", "models/controller.onnx", "reports/train.json", "reports/labels.md"):
        assert (p.root / out).is_file(), out
    assert p.stage_runs() == {s: 1 for s in all_stages}

    second = p.dvc("repro")
    assert _ran(second.stdout) == set(), second.stdout

    # An ingest key changes the stored images, not the frames table: features/labels/samples are skipped,
    # train (which reads the images) re-runs.
    p.set_overrides(["scale=fixture", "ingest.image_width=48"])
    third = p.dvc("repro")
    assert _ran(third.stdout) == {"compose", "ingest", "train"}, third.stdout

    # A train key: only compose and train.
    p.set_overrides(["scale=fixture", "ingest.image_width=48", "train.lr=0.0003"])
    assert _ran(p.dvc("repro").stdout) == {"compose", "train"}
    assert p.stage_runs() == {"compose": 3, "collect": 1, "ingest": 2, "features": 1, "labels": 1, "samples": 1,
                              "train": 3}

    # A key no stage reads except compose: only compose re-runs (its output changes, but no stage's keys do).
    p.set_overrides(["scale=fixture", "ingest.image_width=48", "train.lr=0.0003", "+unused_note=hello"])
    fourth = p.dvc("repro")
    assert _ran(fourth.stdout) == {"compose"}, fourth.stdout


def test_bad_raw_data_stops_cleanly(project_copy):
    """A real rig recording with a bad cell, ingested on its own (collect not run): a one-line message, no output."""
    p = project_copy
    seq = write_synthetic_sequence(p.root / "data" / "raw" / "train" / "s", n_frames=3)
    (seq / "frames.csv").write_text((seq / "frames.csv").read_text().replace("3.0,", "99.0,", 1))
    p.dvc("repro", "compose")
    out = p.dvc("repro", "--single-item", "ingest", check=False)
    assert out.returncode != 0
    assert "line 2, column 'gain_db': 99.0 outside the valid range" in out.stderr + out.stdout
    assert "Traceback" not in out.stderr
    assert not (p.root / "data" / "frames.parquet").exists()
