from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from synthetic_raw import write_synthetic_sequence

from expoctl.errors import InputError
from expoctl.raw.format import SequenceWriter, find_sequences, read_image_rgb, read_png_size, read_sequence_yaml


def test_writer_round_trip(tmp_path):
    seq = write_synthetic_sequence(tmp_path / "train" / "a", n_frames=3, height=24, width=32)
    frames = pd.read_csv(seq / "frames.csv")
    assert list(frames.columns) == ["frame_id", "camera", "timestamp_ns", "gain_db", "exposure_us", "image"]
    assert frames[["frame_id", "camera"]].values.tolist() == [[0, 1], [0, 2], [1, 1], [1, 2], [2, 1], [2, 2]]
    img = read_image_rgb(seq / frames.image[0])
    assert img.shape == (24, 32, 3) and img.dtype == np.uint8
    assert read_png_size(seq / frames.image[0]) == (32, 24)
    assert read_sequence_yaml(seq)["rig"]["resolution"] == [32, 24]


def test_writer_preserves_rgb_order(tmp_path):
    img = np.zeros((4, 4, 3), np.uint8)
    img[..., 0] = 200  # pure red
    with SequenceWriter(tmp_path / "s", {"source": "sim"}) as w:
        w.add_frame(0, 1, 0, 0.0, 100.0, img)
        w.add_frame(0, 2, 0, 0.0, 100.0, img)
    assert read_image_rgb(tmp_path / "s" / "cam1" / "000000.png")[0, 0].tolist() == [200, 0, 0]


def test_writer_exception_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError):
        with SequenceWriter(tmp_path / "s", {"source": "sim"}) as w:
            w.add_frame(0, 1, 0, 0.0, 100.0, np.zeros((4, 4, 3), np.uint8))
            raise RuntimeError("render crashed")
    assert list(tmp_path.iterdir()) == []


def test_find_sequences_skips_camera_dirs(tmp_path):
    write_synthetic_sequence(tmp_path / "train" / "a", n_frames=2)
    write_synthetic_sequence(tmp_path / "test" / "b", n_frames=2)
    assert [p.relative_to(tmp_path).as_posix() for p in find_sequences(tmp_path)] == ["test/b", "train/a"]


def test_read_image_rgb_errors(tmp_path):
    with pytest.raises(InputError, match="missing"):
        read_image_rgb(tmp_path / "nope.png")
    (tmp_path / "bad.png").write_bytes(b"not an image")
    with pytest.raises(InputError, match="corrupt"):
        read_image_rgb(tmp_path / "bad.png")
