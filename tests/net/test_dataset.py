"""Data loading: samples + frames + image store → batches; shared flips; input errors name the problem."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import torch

from expoctl.camera.ranges import gain_to_norm, norm_to_exposure
from expoctl.net.dataset import load_sample_sets, load_sample_sets_from_files
from expoctl.errors import InputError
from tests.support.synthetic_data import make_synthetic_dataset


@pytest.fixture()
def syn(tmp_path):
    return make_synthetic_dataset(tmp_path, n_sequences=3, n_frames=6, hw=(16, 16), seed=1)


def test_batches_match_store_and_frames(syn):
    sets = load_sample_sets_from_files(syn["samples"], syn["frames"], syn["images_dir"], 16, splits=("train", "test"))
    samples = pd.read_parquet(syn["samples"])
    frames = pd.read_parquet(syn["frames"]).set_index(["sequence", "frame_id", "camera"])
    tr = sets["train"]
    assert len(tr) == (samples.split == "train").sum() and tr.store_hw == (16, 16)
    x, y = tr.batch([5])
    row = samples[samples.split == "train"].iloc[5]
    store = np.load(syn["images_dir"] / f"{row.sequence}.npy")
    for k, cam in enumerate((row.cam_t, row.cam_t1, row.cam_t2)):
        fr = frames.loc[(row.sequence, row.frame_id - k, cam)]
        img = store[fr.image_index, cam - 1].transpose(2, 0, 1) / np.float32(255)
        assert torch.equal(x[0, 5 * k:5 * k + 3], torch.from_numpy(img.astype(np.float32)))
        assert float(x[0, 5 * k + 3, 0, 0]) == np.float32(gain_to_norm(fr.gain_db))
    assert torch.equal(y[0], torch.tensor([row.target_gain_norm, row.target_exposure_norm], dtype=torch.float32))
    # each distinct frame is cached once: 8 camera combinations share them
    assert tr.frames.shape[0] <= 2 * 6 * 3


def test_time_step_groups_the_camera_combinations_of_one_frame(syn):
    sets = load_sample_sets_from_files(syn["samples"], syn["frames"], syn["images_dir"], 16, splits=("train", "test"))
    samples = pd.read_parquet(syn["samples"])
    for split, data in sets.items():
        rows = samples[samples.split == split]
        key = rows["sequence"].astype(str) + "/" + rows["frame_id"].astype(str)
        same_key = key.to_numpy()[:, None] == key.to_numpy()[None, :]
        assert np.array_equal(data.time_step[:, None] == data.time_step[None, :], same_key)
        assert np.all(np.bincount(data.time_step) == 8)  # the 2³ combinations of every labelled step


def test_log_exposure_scale_converts_planes_and_targets(syn):
    """samples.parquet holds linear-scaled targets; a log-scaled set carries both planes and targets in log (EV)."""
    lin = load_sample_sets_from_files(syn["samples"], syn["frames"], syn["images_dir"], 16)["train"]
    log = load_sample_sets_from_files(syn["samples"], syn["frames"], syn["images_dir"], 16,
                                      exposure_scale="log")["train"]
    assert (lin.exposure_scale, log.exposure_scale) == ("linear", "log")
    e_lin = norm_to_exposure(lin.targets[:, 1].numpy().astype(np.float64), "linear")
    e_log = norm_to_exposure(log.targets[:, 1].numpy().astype(np.float64), "log")
    np.testing.assert_allclose(e_log, e_lin, rtol=1e-4)  # float32 targets: same exposures, other scaling
    np.testing.assert_allclose(norm_to_exposure(log.exposure_norm.numpy().astype(np.float64), "log"),
                               norm_to_exposure(lin.exposure_norm.numpy().astype(np.float64), "linear"), rtol=1e-4)
    assert torch.equal(log.targets[:, 0], lin.targets[:, 0]) and torch.equal(log.gain_norm, lin.gain_norm)
    x, _ = log.batch([0])
    assert float(x[0, 4, 0, 0]) == float(log.exposure_norm[0, 0])


def test_shared_flip_mirrors_all_three_frames(syn):
    tr = load_sample_sets_from_files(syn["samples"], syn["frames"], syn["images_dir"], 16)["train"]
    x, _ = tr.batch([0, 1])
    xf, _ = tr.batch([0, 1], flip=torch.tensor([True, False]))
    assert torch.equal(xf[0], torch.flip(x[0], dims=[-1]))
    assert torch.equal(xf[1], x[1])


def test_missing_frame_and_store_are_named(syn, tmp_path):
    samples = pd.read_parquet(syn["samples"])
    frames = pd.read_parquet(syn["frames"])
    bad = frames[~((frames.sequence == "syn000") & (frames.frame_id == 1) & (frames.camera == 2))]
    with pytest.raises(InputError, match="sequence syn000 frame 1 camera 2"):
        load_sample_sets(samples, bad, syn["images_dir"], 16)
    with pytest.raises(InputError, match="image store for sequence syn000 not found"):
        load_sample_sets(samples, frames, tmp_path / "nowhere", 16)
    with pytest.raises(InputError, match="missing column"):
        load_sample_sets(samples.drop(columns=["cam_t2"]), frames, syn["images_dir"], 16)
    np.save(syn["images_dir"] / "syn000.npy", np.zeros((6, 2, 16, 16), np.uint8))
    with pytest.raises(InputError, match="syn000.npy: expected uint8"):
        load_sample_sets(samples, frames, syn["images_dir"], 16)
