from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from synthetic_raw import write_synthetic_sequence

from expoctl.errors import ConfigError, InputError
from expoctl.raw.ingest import IngestConfig, assign_split, ingest
from expoctl.raw.format import read_image_rgb


def test_ingest_writes_frames_and_image_store(raw_dir, tmp_path):
    cfg = IngestConfig(image_width=16, image_height=12)
    frames = ingest(raw_dir, tmp_path / "out" / "frames.parquet", tmp_path / "out" / "images", cfg, project_root=tmp_path)
    on_disk = pd.read_parquet(tmp_path / "out" / "frames.parquet")
    assert list(on_disk.columns) == ["sequence", "frame_id", "camera", "timestamp_ns", "gain_db", "exposure_us",
                                     "image_path", "split", "section", "image_index"]
    assert len(on_disk) == len(frames) == 3 * 6 * 2
    assert dict(on_disk.groupby("sequence")["split"].first()) == {
        "seq_train": "train", "seq_validation": "validation", "seq_test": "test"}
    assert set(on_disk["section"]) == {"static", "dynamic"}
    store = np.load(tmp_path / "out" / "images" / "seq_train.npy", mmap_mode="r")
    assert store.shape == (6, 2, 12, 16, 3) and store.dtype == np.uint8
    # Row image_index, axis camera-1 holds the area-downsampled raw PNG.
    import cv2
    r = on_disk[(on_disk.sequence == "seq_train") & (on_disk.frame_id == 4) & (on_disk.camera == 2)].iloc[0]
    full = read_image_rgb(tmp_path / r.image_path)
    np.testing.assert_array_equal(store[r.image_index, 1], cv2.resize(full, (16, 12), interpolation=cv2.INTER_AREA))
    assert on_disk.loc[(on_disk.frame_id == 0) & (on_disk.sequence == "seq_train"), "section"].unique().tolist() == ["static"]


def test_ingest_bad_input_writes_nothing_and_keeps_previous_output(raw_dir, tmp_path):
    out_frames, out_images = tmp_path / "frames.parquet", tmp_path / "images"
    ingest(raw_dir, out_frames, out_images, IngestConfig(16, 12), project_root=tmp_path)
    before = out_frames.read_bytes()
    store_before = (out_images / "seq_test.npy").read_bytes()
    # corrupt one image (found only when decoding, in the second pass) and one CSV cell (first pass)
    (raw_dir / "test" / "seq_test" / "cam1" / "000002.png").write_bytes(b"\x89PNG\r\n\x1a\nbroken")
    with pytest.raises(InputError) as exc:
        ingest(raw_dir, out_frames, out_images, IngestConfig(8, 8), project_root=tmp_path)
    assert "nothing was written" in str(exc.value) and "000002.png" in str(exc.value)
    assert out_frames.read_bytes() == before
    assert (out_images / "seq_test.npy").read_bytes() == store_before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging debris
    frames_csv = raw_dir / "train" / "seq_train" / "frames.csv"
    frames_csv.write_text(frames_csv.read_text().replace("3.0,", "nan,", 1))
    with pytest.raises(InputError, match=r"seq_train/frames.csv: line 2, column 'gain_db'"):
        ingest(raw_dir, out_frames, out_images, IngestConfig(8, 8), project_root=tmp_path)
    assert out_frames.read_bytes() == before


def test_ingest_empty_raw_dir(tmp_path):
    (tmp_path / "raw").mkdir()
    with pytest.raises(InputError, match="no sequences found"):
        ingest(tmp_path / "raw", tmp_path / "f.parquet", tmp_path / "img", IngestConfig())
    assert not (tmp_path / "f.parquet").exists()


def test_duplicate_sequence_names_rejected(tmp_path):
    write_synthetic_sequence(tmp_path / "raw" / "train" / "same", n_frames=2)
    write_synthetic_sequence(tmp_path / "raw" / "test" / "same", n_frames=2)
    with pytest.raises(InputError, match="sequence name 'same' also used"):
        ingest(tmp_path / "raw", tmp_path / "f.parquet", tmp_path / "img", IngestConfig())


def test_split_of_rig_recordings_is_stable_hash(tmp_path):
    cfg = IngestConfig(holdout_validation=0.3, holdout_test=0.3)
    raw = tmp_path / "raw"
    splits = [assign_split(raw / "rig_2026" / f"drive_{i:03d}", raw, cfg) for i in range(200)]
    assert splits == [assign_split(raw / "rig_2026" / f"drive_{i:03d}", raw, cfg) for i in range(200)]
    share = {s: splits.count(s) / 200 for s in ("train", "validation", "test")}
    assert all(abs(share[s] - 0.3) < 0.1 for s in ("validation", "test")), share  # binomial sd ≈ 0.032
    assert assign_split(raw / "test" / "x", raw, cfg) == "test"


@pytest.mark.parametrize("d,key", [
    ({"image_width": 0}, "ingest.image_width"),
    ({"holdout_fractions": {"validation": 0.6, "test": 0.5}}, "ingest.holdout_fractions"),
    ({"holdout_fractions": {"valid": 0.1}}, "ingest.holdout_fractions.valid"),
    ({"image_widht": 10}, "ingest.image_widht"),
])
def test_bad_config(d, key):
    with pytest.raises(ConfigError) as exc:
        IngestConfig.from_dict(d)
    assert exc.value.key == key


def test_ingest_several_raw_dirs(tmp_path):
    write_synthetic_sequence(tmp_path / "raw" / "train" / "it1_a", n_frames=2)
    write_synthetic_sequence(tmp_path / "raw_iter2" / "train" / "it2_a", n_frames=2)
    write_synthetic_sequence(tmp_path / "raw_iter2" / "validation" / "it2_b", n_frames=2)
    frames = ingest([tmp_path / "raw", tmp_path / "raw_iter2"], tmp_path / "f.parquet", tmp_path / "img",
                    IngestConfig(8, 8), project_root=tmp_path)
    assert frames.groupby("sequence")["split"].first().to_dict() == {
        "it1_a": "train", "it2_a": "train", "it2_b": "validation"}
    (tmp_path / "empty").mkdir()
    assert len(ingest([tmp_path / "raw", tmp_path / "empty"], tmp_path / "g.parquet", tmp_path / "img2",
                      IngestConfig(8, 8), project_root=tmp_path)) == 4


def test_one_run_reports_a_bad_csv_cell_and_a_truncated_png_together(tmp_path):
    """Before: the first run reported the CSV cell only (pass 1 reads PNG headers, and a truncated PNG's header is
    whole); the truncated PNG came out of the second run. Now one InputError names both, and nothing is written."""
    seq = write_synthetic_sequence(tmp_path / "raw" / "train" / "s1", n_frames=4)
    frames_csv = seq / "frames.csv"
    lines = frames_csv.read_text().splitlines()
    header = lines[0].split(",")
    row = lines[3].split(",")  # line 4 of the file
    row[header.index("exposure_us")] = "fast"
    lines[3] = ",".join(row)
    frames_csv.write_text("\n".join(lines) + "\n")
    png = seq / "cam2" / "000002.png"
    data = png.read_bytes()
    png.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as exc:
        ingest(tmp_path / "raw", tmp_path / "frames.parquet", tmp_path / "images", IngestConfig(16, 12),
               project_root=tmp_path)
    assert str(exc.value).splitlines() == [
        "2 problem(s) in the raw data; nothing was written:",
        f"{frames_csv}: line 4, column 'exposure_us': not a number ('fast')",
        f"{frames_csv}: line 7, column 'image': {png}: truncated or corrupt PNG ({len(data) // 2} bytes, no end "
        "chunk): unreadable",
    ]
    assert not (tmp_path / "frames.parquet").exists() and not (tmp_path / "images").exists()


def test_one_run_also_finds_a_png_corrupt_in_the_middle(tmp_path):
    """A PNG whose header and end are whole but whose image data is broken is found only by decoding: with any
    other problem in the raw data, ingest decodes every image before it stops, so it is in the same error."""
    a = write_synthetic_sequence(tmp_path / "raw" / "train" / "a", n_frames=4)
    b = write_synthetic_sequence(tmp_path / "raw" / "train" / "b", n_frames=4, seed=1)
    (a / "cam1" / "000003.png").unlink()  # a missing frame
    png = b / "cam1" / "000001.png"
    data = bytearray(png.read_bytes())
    data[60:200] = bytes(140)  # zeroes over the compressed image data, the IEND end chunk intact
    png.write_bytes(bytes(data))
    with pytest.raises(InputError) as exc:
        ingest(tmp_path / "raw", tmp_path / "frames.parquet", tmp_path / "images", IngestConfig(16, 12),
               project_root=tmp_path)
    assert str(exc.value).splitlines() == [
        "2 problem(s) in the raw data; nothing was written:",
        f"{a / 'frames.csv'}: line 8, column 'image': image file {a / 'cam1' / '000003.png'} missing",
        f"{b / 'frames.csv'}: line 4, column 'image': {png}: unreadable or corrupt image",
    ]
