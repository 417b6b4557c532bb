from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from expoctl.io import atomic_dir, atomic_path, write_json, write_parquet, write_png


def test_exception_mid_write_keeps_previous_file(tmp_path):
    target = tmp_path / "t.parquet"
    write_parquet(pd.DataFrame({"a": [1, 2]}), target)
    before = target.read_bytes()
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("crash")
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["t.parquet"]


def test_unserialisable_json_keeps_previous(tmp_path):
    target = tmp_path / "m.json"
    write_json({"x": np.float32(1.5), "n": np.int64(3)}, target)
    assert json.loads(target.read_text()) == {"n": 3, "x": 1.5}
    with pytest.raises(TypeError):
        write_json({"bad": object()}, target)
    assert json.loads(target.read_text()) == {"n": 3, "x": 1.5}


def test_atomic_dir_replaces_whole_or_nothing(tmp_path):
    d = tmp_path / "images"
    with atomic_dir(d) as tmp:
        (tmp / "a.npy").write_bytes(b"1")
    with pytest.raises(ValueError):
        with atomic_dir(d) as tmp:
            (tmp / "b.npy").write_bytes(b"2")
            raise ValueError
    assert [p.name for p in d.iterdir()] == ["a.npy"]
    with atomic_dir(d) as tmp:
        (tmp / "c.npy").write_bytes(b"3")
    assert [p.name for p in d.iterdir()] == ["c.npy"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["images"]


def test_write_png_rgb_round_trip(tmp_path):
    import cv2
    img = np.zeros((3, 5, 3), np.uint8)
    img[..., 2] = 77  # blue
    write_png(img, tmp_path / "x.png")
    assert cv2.imread(str(tmp_path / "x.png"))[0, 0].tolist() == [77, 0, 0]  # OpenCV reads BGR


def test_outputs_get_usual_permissions(tmp_path):
    import os
    write_json({"a": 1}, tmp_path / "x.json")
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "x.json").stat().st_mode & 0o777 == 0o666 & ~mask
    with atomic_dir(tmp_path / "d"):
        pass
    assert (tmp_path / "d").stat().st_mode & 0o777 == 0o777 & ~mask
