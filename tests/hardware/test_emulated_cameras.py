"""`expoctl drive` and `expoctl record` against two emulated GigE Vision cameras (conftest: private namespace,
loopback only), run as a user runs them; their output goes through `expoctl validate` and `ingest`."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from emulated import GAIN_DB_PER_RAW, camera_args

from expoctl.controllers.base import Settings
from expoctl.errors import InputError
from expoctl.raw.ingest import IngestConfig, ingest
from expoctl.sim.protocol import PerturbationConfig, perturb


def _validate(path: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "expoctl.cli", "validate", str(path)], capture_output=True, text=True)


def _frames(path: Path) -> pd.DataFrame:
    return pd.read_csv(path / "frames.csv")


def _grey_means(seq: Path, frames: pd.DataFrame) -> np.ndarray:
    import cv2

    return np.array([cv2.imread(str(seq / p), cv2.IMREAD_GRAYSCALE).mean() for p in frames["image"]])


def _emulator_mean(gain_db: float, exposure_us: float) -> float:
    """Mean grey level the emulator's test pattern has at these settings, as measured on it: a diagonal ramp
    (x + y) mod 255 scaled by 1 + raw gain + log10(exposure / 10 ms), clipped to 0–255 (fits within 1.5 levels: the
    ramp also shifts by one level per frame, which this ignores)."""
    scale = 1.0 + gain_db / GAIN_DB_PER_RAW + np.log10(exposure_us / 1e4)
    ramp = (np.arange(640)[None, :] + np.arange(480)[:, None]) % 255
    return float(np.clip(ramp * scale, 0, 255).astype(np.uint8).mean()) if scale > 0 else 0.0


def _assert_images_match_settings(frames: pd.DataFrame, means: np.ndarray, share: float) -> None:
    """The settings on each row are those the image was exposed with: the emulator's brightness at them matches the
    image (for `share` of the rows; a command written while the camera is filling a frame may miss that frame)."""
    pred = np.array([_emulator_mean(g, e) for g, e in zip(frames["gain_db"], frames["exposure_us"])])
    ok = np.abs(pred - means) <= 3.0  # other settings differ by tens of levels (perturbation: up to ±50 %)
    assert ok.mean() >= share, list(zip(pred.round(1), means.round(1)))


def _assert_device_values(frames: pd.DataFrame) -> None:
    """The emulator holds whole microseconds and whole GainRaw steps: values read back from it are quantised that
    way, while the controllers command arbitrary floats — so these rows are what the camera reports, not commands."""
    assert (frames["exposure_us"] == frames["exposure_us"].round()).all()
    steps = frames["gain_db"] / GAIN_DB_PER_RAW
    assert np.allclose(steps, steps.round())


def test_drive_agae_converges_on_the_emulators_brightness(emulators, tmp_path):
    cam_a, _ = emulators.ids()
    out = tmp_path / "drive_agae"
    res = emulators.expoctl("drive", "--camera", cam_a, "--controller", "agae", "--frames", "60", "--out", str(out),
                            "--initial-exposure-us", "1000", "--initial-gain-db", "0", *camera_args())
    assert res.returncode == 0, res.stderr
    table = [l.split() for l in res.stdout.splitlines() if l.strip() and l.split()[0].isdigit()]
    assert len(table) == 60  # one timing line per frame: frame, gain, exposure, mean, controller ms, delay
    assert sum(row[4] != "-" for row in table) >= 59 and sum(row[5] != "-" for row in table) >= 5
    assert "actuation delay" in res.stdout and "from readback" in res.stdout
    ok = _validate(out)
    assert ok.returncode == 0 and "60 frames (one camera), 640x480" in ok.stdout, ok.stderr
    frames = _frames(out)
    assert (frames["camera"] == 1).all() and len(frames) == 60
    _assert_device_values(frames)
    means = _grey_means(out, frames)
    # free-running, a frame already in flight when a command is written can carry the old settings; were the rows
    # commands instead of what the camera reports, every changed frame (~25 of the first 30) would miss
    _assert_images_match_settings(frames, means, share=0.8)
    assert means[:5].min() < 5.0  # 1 ms is black on the emulator (the very first frame may predate the command)
    last = means[-15:]
    assert 60.0 < last.mean() < 180.0 and np.ptp(last) < 3.0, means  # settled, neither dark nor clipped
    exposure = frames["exposure_us"].to_numpy()
    assert np.ptp(exposure[-15:]) / exposure[-15:].mean() < 0.03 and exposure[-1] > 3000.0
    # the last row against the camera itself, asked through Aravis directly (no expoctl code): the loop ends after
    # its last frame, so the camera still holds that frame's settings
    ask = ("import gi; gi.require_version('Aravis', '0.8'); from gi.repository import Aravis; "
           "c = Aravis.Camera.new('127.0.0.1'); print(c.get_exposure_time(), c.get_gain())")
    held = emulators.run([sys.executable, "-c", ask])
    assert held.returncode == 0, held.stderr
    exposure_us, gain_raw = (float(v) for v in held.stdout.split())
    assert frames["exposure_us"].iat[-1] == exposure_us and frames["gain_db"].iat[-1] == gain_raw * GAIN_DB_PER_RAW
    meta = yaml.safe_load((out / "sequence.yaml").read_text())
    assert meta["cameras"] == 1 and meta["drive"]["frames"] == 60 and meta["camera1"]["settings_source"] == "readback"
    assert meta["camera1"]["features"]["gain"] == "GainRaw" and meta["camera1"]["features"]["exposure"] == "ExposureTimeAbs"
    assert not (out / "cam2").exists()
    with pytest.raises(InputError, match="a one-camera sequence .* training needs two cameras"):
        ingest([out.parent], tmp_path / "frames.parquet", tmp_path / "images", IngestConfig(), project_root=tmp_path)
    assert not (tmp_path / "frames.parquet").exists()


def test_drive_learned_network_through_onnx(emulators, tmp_path, tiny_model):
    cam_a, _ = emulators.ids()
    out = tmp_path / "drive_learned"
    res = emulators.expoctl("drive", "--camera", cam_a, "--controller", "learned", "--model", str(tiny_model),
                            "--frames", "30", "--out", str(out), *camera_args())
    assert res.returncode == 0, res.stderr
    meta = yaml.safe_load((out / "sequence.yaml").read_text())
    assert meta["controller"]["params"]["backend"] == "onnx" and meta["controller"]["params"]["num_threads"] == 1
    assert meta["drive"]["controller_ms"]["median"] > 0
    assert _validate(out).returncode == 0
    _assert_device_values(_frames(out))


def test_record_validates_ingests_and_follows_the_shared_protocol(emulators, tmp_path):
    cam_a, cam_b = emulators.ids()
    raw = tmp_path / "raw"
    out = raw / "train" / "rig_000"
    res = emulators.expoctl("record", "--camera1", cam_a, "--camera2", "127.0.0.2", "--frames", "24", "--warmup", "6",
                            "--seed", "7", "--baseline-m", "0.12", "--intrinsics", "500", "500", "320", "240",
                            "--out", str(out), *camera_args())
    assert res.returncode == 0, res.stderr
    assert "24 frame pairs (completed)" in res.stdout
    ok = _validate(out)
    assert ok.returncode == 0 and "24 frame pairs, 640x480" in ok.stdout, ok.stderr
    meta = yaml.safe_load((out / "sequence.yaml").read_text())
    assert meta["rig"]["baseline_m"] == 0.12 and meta["pairing"]["tolerance_ms"] == 10.0
    assert meta["rig"]["intrinsics"] == {"fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0}
    assert meta["pairing"]["max_offset_ms"] <= 10.0 and meta["camera2"]["serial"] == cam_b
    frames = _frames(out)
    _assert_device_values(frames)
    c1 = frames[frames.camera == 1].set_index("frame_id")
    c2 = frames[frames.camera == 2].set_index("frame_id")
    # pairs: every frame id has both cameras, host receive times within the documented tolerance
    assert list(c1.index) == list(c2.index) == list(range(24))
    assert (abs(c1["timestamp_ns"] - c2["timestamp_ns"]) <= 10_000_000).all()
    # camera 2 = the simulator's perturbation of camera 1's settings (frame index = recorded frame + warm-up),
    # up to the emulator's rounding (whole µs; 6 dB gain steps)
    for fid in range(24):
        want = perturb(Settings(c1.at[fid, "gain_db"], c1.at[fid, "exposure_us"]), fid + 6, 7, PerturbationConfig())
        assert abs(c2.at[fid, "exposure_us"] - want.exposure_us) <= 2.0, fid
        assert c2.at[fid, "gain_db"] == round(want.gain_db / GAIN_DB_PER_RAW) * GAIN_DB_PER_RAW, fid
    assert (c2["exposure_us"] != c1["exposure_us"]).mean() > 0.9
    # triggered after the write: every image was exposed with the settings on its row
    _assert_images_match_settings(frames, _grey_means(out, frames), share=1.0)
    table = ingest([raw], tmp_path / "frames.parquet", tmp_path / "images",
                   IngestConfig(image_width=32, image_height=24), project_root=tmp_path)
    assert len(table) == 48 and set(table["camera"]) == {1, 2} and set(table["split"]) == {"train"}
    assert np.load(tmp_path / "images" / "rig_000.npy", mmap_mode="r").shape == (24, 2, 24, 32, 3)


def test_ctrl_c_stops_recording_with_a_valid_sequence(emulators, tmp_path, tiny_model):
    """Also the paper's second iteration: the network as camera 1's reference."""
    cam_a, cam_b = emulators.ids()
    out = tmp_path / "interrupted"
    proc = emulators.popen_expoctl("record", "--camera1", cam_a, "--camera2", cam_b, "--warmup", "2",
                                   "--reference", "learned", "--model", str(tiny_model),
                                   "--baseline-m", "0.1", "--out", str(out), *camera_args())
    _wait_for_line(proc, "frame 25:")
    proc.send_signal(signal.SIGINT)  # `ip netns exec` passes it on to expoctl
    stdout, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0, stderr
    assert "(interrupted)" in stdout and "Traceback" not in stderr
    ok = _validate(out)
    assert ok.returncode == 0, ok.stderr
    meta = yaml.safe_load((out / "sequence.yaml").read_text())
    assert meta["stopped"] == "interrupted" and meta["reference_controller"]["name"] == "learned"
    assert len(_frames(out)) >= 2 * 26


def test_camera_that_disappears_mid_run(emulators, tmp_path):
    cam_a, cam_b = emulators.ids()
    out = tmp_path / "lost"
    proc = emulators.popen_expoctl("record", "--camera1", cam_a, "--camera2", cam_b, "--warmup", "2",
                                   "--frames", "2000", "--baseline-m", "0.1", "--out", str(out), *camera_args())
    try:
        _wait_for_line(proc, "frame 25:")
        emulators.stop(1)  # camera B's emulator killed: the camera vanishes
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        emulators.start(1)
    assert proc.returncode != 0
    assert stderr.startswith("expoctl record: error: camera ") and cam_b in stderr and "Traceback" not in stderr
    assert f"saved in {out}" in stderr and "expoctl validate accepts it" in stderr
    ok = _validate(out)
    assert ok.returncode == 0, ok.stderr
    n = len(_frames(out)) // 2
    assert 26 <= n < 2000
    assert yaml.safe_load((out / "sequence.yaml").read_text())["stopped"].startswith("camera failed")


def test_unknown_camera_and_out_of_range_limits_are_named(emulators, tmp_path):
    cam_a, cam_b = emulators.ids()
    listing = emulators.expoctl("cameras")
    assert listing.returncode == 0 and cam_a in listing.stdout and cam_b in listing.stdout
    assert "127.0.0.2" in listing.stdout
    res = emulators.expoctl("drive", "--camera", "NO-SUCH-CAM", "--controller", "agae", "--frames", "5",
                            "--out", str(tmp_path / "x"), *camera_args())
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert "camera 'NO-SUCH-CAM' not found; cameras found: " in res.stderr and cam_a in res.stderr
    res = emulators.expoctl("drive", "--camera", cam_a, "--controller", "agae", "--frames", "5",
                            "--out", str(tmp_path / "y"), "--gain-max-db", "90", "--exposure-max-us", "2e7",
                            *camera_args())
    assert res.returncode == 2 and "Traceback" not in res.stderr
    assert f"camera {cam_a}: --gain-max-db 90 dB is outside camera {cam_a}'s range 0–60 dB" in res.stderr
    assert f"--exposure-max-us 2e+07 µs is outside camera {cam_a}'s range 10–1e+07 µs" in res.stderr
    res = emulators.expoctl("drive", "--camera", cam_a, "--controller", "agae", "--frames", "5",
                            "--out", str(tmp_path / "z"), "--width", "640")  # no --gain-db-per-raw
    assert res.returncode == 2 and "GainRaw" in res.stderr and "--gain-db-per-raw" in res.stderr
    res = emulators.expoctl("record", "--camera1", cam_a, "--camera2", "127.0.0.1", "--baseline-m", "0.1",
                            "--out", str(tmp_path / "w"), *camera_args())
    assert res.returncode == 2 and f"{cam_a} and 127.0.0.1 are the same camera" in res.stderr
    assert not any(p.exists() for p in (tmp_path / "x", tmp_path / "y", tmp_path / "z", tmp_path / "w"))


def test_existing_output_is_never_replaced(tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "keep.txt").write_text("user data")
    res = subprocess.run([sys.executable, "-m", "expoctl.cli", "drive", "--camera", "any", "--controller", "agae",
                          "--frames", "5", "--out", str(out)], capture_output=True, text=True)
    assert res.returncode == 2 and "already exists" in res.stderr and (out / "keep.txt").read_text() == "user data"


def _wait_for_line(proc: subprocess.Popen, text: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if text in line:
            return
        if not line and proc.poll() is not None:
            raise AssertionError(f"expoctl exited ({proc.returncode}) before printing {text!r}: {proc.stderr.read()}")
    raise AssertionError(f"no {text!r} within {timeout_s} s")


def test_latency_from_images_and_from_read_back(emulators):
    """The emulator applies a written setting from its next frame on; the image shows it after >= 1 camera frame, and
    never before the read-back metadata does (read-back is a lower bound)."""
    cam_a, _ = emulators.ids()
    res = emulators.expoctl("latency", "--camera", cam_a, "--steps", "6", "--json", *camera_args())
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout.splitlines()[-1])
    assert summary["settings_source"] == "readback" and summary["steps_without_image_change"] == 0
    image, meta = summary["image_delay_frames"]["values"], summary["metadata_delay_frames"]["values"]
    assert len(image) == len(meta) == 6 and set(meta) == {1}
    assert all(1 <= i <= 4 for i in image) and summary["image_delay_frames"]["median"] >= 1
