import argparse

import cv2
import numpy as np
import pytest
import yaml

from expoctl.controllers.base import Settings
from expoctl.errors import InputError
from expoctl.sim import preview
from expoctl.sim.preview import PreviewFrame, _select, annotate, contact_sheet


def frames_with_exit(n=40, h=48, w=64):
    """A dark tunnel that opens into daylight at frame 20; the 'camera' needs 6 frames to adapt."""
    out = []
    for t in range(n):
        level = 60 if t < 20 else (255 if t < 26 else 120)
        section = "dynamic" if 15 <= t <= 30 else "static"
        out.append(PreviewFrame(t, Settings(10.0 if t < 23 else 0.0, 20000.0 if t < 23 else 500.0),
                                np.full((h, w, 3), level, np.uint8), section))
    return out


SECTIONS = [{"start_frame": 0, "end_frame": 14, "kind": "static"}, {"start_frame": 15, "end_frame": 30, "kind": "dynamic"},
            {"start_frame": 31, "end_frame": 39, "kind": "static"}]


def test_transition_rows_spread_over_the_dynamic_section():
    frames = frames_with_exit()
    rows = _select(frames, SECTIONS, "transitions", columns=8, max_rows=4)
    assert len(rows) == 1 and len(rows[0]) == 8
    picked = [frames[p].frame_index for p in rows[0]]
    assert picked == [15, 17, 19, 21, 24, 26, 28, 30]
    uniform = _select(frames, SECTIONS, "uniform", columns=5, max_rows=2)
    assert [len(r) for r in uniform] == [5, 5] and frames[uniform[-1][-1]].frame_index == 39


def test_annotation_draws_text_in_the_corner_only():
    f = frames_with_exit()[0]
    stamped = annotate(f.image, f)
    diff = np.any(stamped != f.image, axis=2)
    ys, xs = np.nonzero(diff)
    assert ys.max() < 40 and xs.min() < 10 and xs.max() < f.image.shape[1]  # only the top-left box changed
    box = stamped[: ys.max() + 1, : xs.max() + 1]
    assert (box.max(axis=2) > 200).sum() > 30  # bright text on it
    assert (box.max(axis=2) < 30).sum() > 100  # on a darkened background (60 → 24)
    assert np.array_equal(f.image, frames_with_exit()[0].image)  # input untouched


def test_contact_sheet_layout_and_timeline():
    frames = frames_with_exit()
    rows = _select(frames, SECTIONS, "transitions", columns=8, max_rows=4)
    sheet = contact_sheet(frames, rows, columns=8, thumb_width=100, title="test")
    assert sheet.dtype == np.uint8 and sheet.ndim == 3
    assert sheet.shape[1] == 8 * 104 + 4
    # thumbnails 100x75 in one row below a 26-px title bar: frames 15, 17, 19 (tunnel), 21, 24 (saturated exit), 26 …
    y0 = 26 + 4 + 40
    centre = [sheet[y0, 4 + k * 104 + 50].tolist() for k in range(8)]
    assert centre == [[60] * 3] * 3 + [[255] * 3] * 2 + [[120] * 3] * 3
    assert sheet.shape[0] > 26 + 83 + 150  # the timeline sits below


def test_bad_arguments_raise_input_error(tmp_path):
    p = argparse.ArgumentParser()
    preview.add_arguments(p)
    with pytest.raises(InputError, match="--columns"):
        preview.run(p.parse_args(["--city", "train", "--columns", "0"]))
    with pytest.raises(InputError, match="not found"):
        preview.run(p.parse_args(["--city", str(tmp_path / "nope.yaml")]))


def test_preview_end_to_end_tiny(tmp_path):
    city = tmp_path / "small_train.yaml"
    city.write_text(yaml.safe_dump({"base": "train", "textures": {"tile_px": 256}}))
    p = argparse.ArgumentParser()
    preview.add_arguments(p)
    out = tmp_path / "sheet.png"
    args = p.parse_args(["--city", str(city), "--traversal", "1", "--frames", "12", "--width", "48", "--height", "36",
                         "--columns", "4", "--thumb-width", "64", "--out", str(out)])
    assert preview.run(args) == 0
    img = cv2.imread(str(out))
    assert img is not None and img.shape[1] == 4 * 68 + 4


def test_video_has_every_frame(tmp_path):
    from expoctl.sim.preview import write_video

    frames = frames_with_exit()
    path = tmp_path / "run.mp4"
    write_video(frames, path, 15.0)
    cap = cv2.VideoCapture(str(path))
    n, levels = 0, []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        n += 1
        levels.append(float(img[30:, :].mean()))  # below the text
    assert n == len(frames) and cap.get(cv2.CAP_PROP_FPS) == 15.0
    assert abs(levels[10] - 60) < 8 and abs(levels[22] - 255) < 8 and abs(levels[35] - 120) < 8

