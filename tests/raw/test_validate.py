"""Every bad-input case of the raw format yields a message naming file, row and column."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from synthetic_raw import write_synthetic_sequence

from expoctl.raw.validate import check_sequence, validate_raw_dir


@pytest.fixture
def seq(tmp_path: Path) -> Path:
    return write_synthetic_sequence(tmp_path / "raw" / "train" / "s0", n_frames=4)


def _edit_csv(seq: Path, fn) -> None:
    p = seq / "frames.csv"
    lines = p.read_text().splitlines()
    p.write_text("\n".join(fn(lines)) + "\n")


def _set_cell(seq: Path, line: int, column: str, value: str) -> None:
    def fn(lines):
        header = lines[0].split(",")
        cells = lines[line - 1].split(",")
        cells[header.index(column)] = value
        lines[line - 1] = ",".join(cells)
        return lines
    _edit_csv(seq, fn)


def test_valid_sequence_has_no_problems_and_a_summary(seq):
    check = check_sequence(seq)
    assert check.ok, check.problems
    assert check.n_frames == 4 and check.image_size == (64, 48)


def test_corrupt_png(seq):
    (seq / "cam2" / "000001.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    (problem,) = check_sequence(seq).problems
    assert "frames.csv: line 5, column 'image'" in problem and "000001.png" in problem and "corrupt" in problem


def test_missing_image_file(seq):
    (seq / "cam1" / "000002.png").unlink()
    (problem,) = check_sequence(seq).problems
    assert "line 6, column 'image'" in problem and "missing" in problem


def test_image_size_differs(seq):
    big = np.zeros((50, 64, 3), np.uint8)
    cv2.imwrite(str(seq / "cam1" / "000003.png"), big)
    problems = check_sequence(seq).problems
    assert any("image sizes differ" in p and "64x50" in p and "64x48" in p for p in problems), problems


def test_misspelled_column(seq):
    _edit_csv(seq, lambda lines: [lines[0].replace("exposure_us", "exposure_ms")] + lines[1:])
    (problem,) = check_sequence(seq).problems
    assert "missing column 'exposure_us'" in problem and "exposure_ms" in problem


def test_missing_column(seq):
    _edit_csv(seq, lambda lines: [",".join(l.split(",")[:2] + l.split(",")[3:]) for l in lines])  # drop timestamp_ns
    (problem,) = check_sequence(seq).problems
    assert "missing column 'timestamp_ns'" in problem


@pytest.mark.parametrize("column,value,words", [
    ("gain_db", "abc", "not a number"),
    ("gain_db", "nan", "not a number"),
    ("gain_db", "31", "outside the valid range"),
    ("gain_db", "-0.5", "outside the valid range"),
    ("exposure_us", "10", "outside the valid range"),
    ("exposure_us", "30001", "outside the valid range"),
    ("exposure_us", "inf", "not finite"),
    ("camera", "3", "outside the valid range"),
    ("frame_id", "1.5", "not an integer"),
])
def test_bad_numeric_cell(seq, column, value, words):
    _set_cell(seq, 4, column, value)
    problems = check_sequence(seq).problems
    assert any(f"line 4, column '{column}'" in p and words in p for p in problems), problems


def test_duplicate_frame_camera(seq):
    _edit_csv(seq, lambda lines: lines + [lines[3]])
    problems = check_sequence(seq).problems
    assert any("line 10: duplicate (frame_id 1, camera 1)" in p for p in problems), problems


def test_frame_without_partner(seq):
    _edit_csv(seq, lambda lines: [l for i, l in enumerate(lines) if i != 4])  # drop frame 1 camera 2
    (problem,) = check_sequence(seq).problems
    assert "frame_id 1 has camera 1 but no camera 2 partner" in problem


def test_non_monotonic_timestamps(seq):
    _set_cell(seq, 6, "timestamp_ns", "10")  # frame 2 camera 1 earlier than frame 1
    problems = check_sequence(seq).problems
    assert any("line 6, column 'timestamp_ns'" in p and "does not increase" in p for p in problems), problems


def test_empty_sequence(seq):
    _edit_csv(seq, lambda lines: lines[:1])
    (problem,) = check_sequence(seq).problems
    assert "empty sequence" in problem


def test_missing_sequence_yaml(seq):
    (seq / "sequence.yaml").unlink()
    (problem,) = check_sequence(seq).problems
    assert "missing sequence.yaml" in problem


def test_malformed_sequence_yaml(seq):
    (seq / "sequence.yaml").write_text("source: sim\nrig: [unclosed\n")
    (problem,) = check_sequence(seq).problems
    assert "sequence.yaml: malformed YAML" in problem


def test_sequence_yaml_bad_values(seq):
    meta = yaml.safe_load((seq / "sequence.yaml").read_text())
    meta["source"] = "camera"
    meta["rig"]["fps"] = 0
    meta["sections"][0]["kind"] = "moving"
    (seq / "sequence.yaml").write_text(yaml.safe_dump(meta))
    problems = check_sequence(seq).problems
    assert any("'source' must be one of" in p for p in problems)
    assert any("'rig.fps' must be a positive number" in p for p in problems)
    assert any("sections[0].kind" in p for p in problems)


def test_all_problems_reported_at_once(seq):
    _set_cell(seq, 2, "gain_db", "40")
    _set_cell(seq, 3, "exposure_us", "x")
    (seq / "sequence.yaml").unlink()
    assert len(validate_raw_dir(seq.parent.parent)) == 3


def test_cli_exit_codes_and_output(seq):
    exe = [sys.executable, "-m", "expoctl.cli", "validate"]
    ok = subprocess.run(exe + [str(seq.parent.parent)], capture_output=True, text=True)
    assert ok.returncode == 0 and "OK — 4 frame pairs, 64x48" in ok.stdout
    _set_cell(seq, 3, "gain_db", "nan")
    bad = subprocess.run(exe + [str(seq.parent.parent)], capture_output=True, text=True)
    assert bad.returncode == 1 and "line 3, column 'gain_db'" in bad.stderr and "Traceback" not in bad.stderr


def test_three_problems_in_one_pass_and_no_opencv_warnings(seq):
    """A bad value on one row must not hide a corrupt PNG or a missing camera-2 partner elsewhere (issue 24 §6)."""
    _set_cell(seq, 2, "gain_db", "abc")  # frame 0 camera 1
    (seq / "cam2" / "000002.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)  # frame 2 camera 2, line 7
    _edit_csv(seq, lambda lines: [l for i, l in enumerate(lines) if i != 8])  # drop frame 3 camera 2
    problems = check_sequence(seq).problems
    assert len(problems) == 3, problems
    assert "line 2, column 'gain_db': not a number" in problems[0]
    assert any("line 7, column 'image'" in p and "000002.png" in p and "corrupt" in p for p in problems), problems
    assert any("frame_id 3 has camera 1 but no camera 2 partner" in p for p in problems), problems
    # through the CLI: every problem on stderr, nothing from OpenCV itself, no traceback
    exe = [sys.executable, "-m", "expoctl.cli", "validate", str(seq)]
    res = subprocess.run(exe, capture_output=True, text=True)
    assert res.returncode == 1
    lines = [l for l in res.stderr.splitlines() if l.strip()]
    assert lines[:3] == problems and "1 of 1 sequence(s) have problems" in lines[3], lines
    assert len(lines) == 4 and "WARN" not in res.stderr and "libpng" not in res.stderr, res.stderr


def _one_camera(seq: Path) -> None:
    meta = yaml.safe_load((seq / "sequence.yaml").read_text())
    meta["cameras"] = 1
    del meta["rig"]["baseline_m"]
    (seq / "sequence.yaml").write_text(yaml.safe_dump(meta))
    _edit_csv(seq, lambda lines: [l for i, l in enumerate(lines) if i == 0 or l.split(",")[1] == "1"])


def test_one_camera_sequence_is_valid_when_declared(seq):
    _one_camera(seq)
    check = check_sequence(seq)
    assert check.ok and check.n_cameras == 1 and check.n_frames == 4, check.problems
    meta = yaml.safe_load((seq / "sequence.yaml").read_text())
    del meta["cameras"]  # undeclared: a dual-camera sequence whose camera 2 is missing everywhere
    (seq / "sequence.yaml").write_text(yaml.safe_dump(meta))
    problems = check_sequence(seq).problems
    assert any("'rig.baseline_m'" in p for p in problems)
    assert sum("no camera 2 partner" in p for p in problems) == 4, problems


def test_one_camera_sequence_rejects_camera_2_rows_and_bad_count(seq):
    _one_camera(seq)
    _edit_csv(seq, lambda lines: lines + [lines[1].replace(",1,", ",2,", 1).replace("cam1/", "cam2/")])
    (problem,) = check_sequence(seq).problems
    assert "line 6, column 'camera': 2 outside the valid range 1–1 (sequence.yaml says cameras: 1)" in problem
    meta = yaml.safe_load((seq / "sequence.yaml").read_text())
    meta["cameras"] = 3
    (seq / "sequence.yaml").write_text(yaml.safe_dump(meta))
    assert any("key 'cameras' must be 1" in p for p in check_sequence(seq).problems)


def test_header_only_check_finds_a_truncated_png(seq):
    """`--no-decode` / ingest's first pass read PNG headers only; a PNG cut short still has its header, but not its
    end chunk, and is reported without decoding the whole sequence."""
    png = seq / "cam1" / "000001.png"
    data = png.read_bytes()
    png.write_bytes(data[:-40])
    assert check_sequence(seq, decode_images=False).problems == [
        f"{seq / 'frames.csv'}: line 4, column 'image': {png}: truncated or corrupt PNG ({len(data) - 40} bytes, no "
        "end chunk): unreadable"]
