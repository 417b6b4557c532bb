"""Real recordings as training data: validated in one pass, copied whole, the source never touched."""

from __future__ import annotations

import pytest
from synthetic_raw import write_synthetic_sequence

from expoctl.errors import InputError
from expoctl.raw.recordings import copy_recordings


def _tree(d):
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_copies_every_sequence_with_its_split_and_leaves_the_source(tmp_path):
    src = tmp_path / "recordings"
    write_synthetic_sequence(src / "train" / "rig_000", n_frames=4)
    write_synthetic_sequence(src / "validation" / "rig_001", n_frames=6, seed=1)
    before = _tree(src)
    out = tmp_path / "raw"
    write_synthetic_sequence(out / "train" / "old", n_frames=2)  # the previous contents are replaced whole
    summaries = copy_recordings(src, out)
    assert _tree(src) == before
    assert _tree(out) == before
    assert [(s["sequence"], s["split"], s["n_frames"], s["n_dynamic_sections"]) for s in summaries] == [
        ("train/rig_000", "train", 4, 1), ("validation/rig_001", "validation", 6, 1)]


def test_every_problem_of_every_sequence_at_once_and_nothing_written(tmp_path):
    src = tmp_path / "recordings"
    a = write_synthetic_sequence(src / "train" / "a", n_frames=3)
    b = write_synthetic_sequence(src / "train" / "b", n_frames=3)
    (a / "frames.csv").write_text((a / "frames.csv").read_text().replace("3.0,", "99.0,", 1))
    (b / "frames.csv").write_text((b / "frames.csv").read_text().replace("cam2/000001.png", "cam2/missing.png"))
    out = tmp_path / "raw"
    write_synthetic_sequence(out / "train" / "kept", n_frames=2)
    kept = _tree(out)
    with pytest.raises(InputError) as exc:
        copy_recordings(src, out)
    msg = str(exc.value)
    assert f"{a / 'frames.csv'}" in msg and "99.0 outside the valid range" in msg
    assert "missing.png" in msg
    assert _tree(out) == kept


@pytest.mark.parametrize("make,words", [
    (lambda d: None, "the recordings directory does not exist"),
    (lambda d: d.mkdir(), "no recorded sequences"),
])
def test_missing_or_empty_recordings_directory(tmp_path, make, words):
    src = tmp_path / "recordings"
    make(src)
    with pytest.raises(InputError, match=words):
        copy_recordings(src, tmp_path / "raw")
    assert not (tmp_path / "raw").exists()
