"""The open-loop camera-follow probe: exact slopes for networks whose dependence on the input settings is known."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch import nn

from expoctl.net.follow import camera_follow, settings_ev, single_camera_pairs
from expoctl.net.dataset import load_sample_sets_from_files
from tests.support.synthetic_data import make_synthetic_dataset

GAIN_T, EXPOSURE_T = 3, 4  # channels of frame t's settings planes (expoctl.net.preprocess.CHANNEL_NAMES)


class Mix(nn.Module):
    """output = k · (frame t's normalised settings) + (1 − k) · constant: under log exposure scaling EV is linear in
    the normalised settings, so its follow is exactly k."""

    def __init__(self, k: float, constant=(0.3, 0.6)):
        super().__init__()
        self.k, self.constant = k, torch.tensor(constant)

    def forward(self, x):
        held = x[:, [GAIN_T, EXPOSURE_T], 0, 0]
        return self.k * held + (1 - self.k) * self.constant


@pytest.fixture(scope="module")
def validation(tmp_path_factory):
    p = make_synthetic_dataset(tmp_path_factory.mktemp("syn"), n_sequences=3, n_frames=16, hw=(16, 16), seed=4)
    return load_sample_sets_from_files(p["samples"], p["frames"], p["images_dir"], 16, splits=("validation",),
                                       exposure_scale="log")["validation"]


def test_pairs_are_the_single_camera_samples_of_one_time_step(validation):
    i1, i2 = single_camera_pairs(validation)
    assert len(i1) == len(np.unique(validation.time_step)) > 0  # every labelled step has all 8 combinations
    assert np.array_equal(validation.time_step[i1], validation.time_step[i2])
    assert np.all(validation.cameras[i1] == 1) and np.all(validation.cameras[i2] == 2)


@pytest.mark.parametrize("k", [0.0, 0.5, 1.0])
def test_follow_is_the_weight_on_the_input_settings(validation, k):
    r = camera_follow(Mix(k), validation)
    assert r["n_used"] >= 2
    assert r["follow"] == pytest.approx(k, abs=1e-4)
    i1, _ = single_camera_pairs(validation)
    in1 = settings_ev(validation.gain_norm[i1, 0].numpy(), validation.exposure_norm[i1, 0].numpy(), "log")
    out1 = settings_ev(k * validation.gain_norm[i1, 0].numpy() + (1 - k) * 0.3,
                       k * validation.exposure_norm[i1, 0].numpy() + (1 - k) * 0.6, "log")
    assert r["bias_ev"] == pytest.approx(float(np.median(out1 - in1)), abs=1e-4)
    if k < 1:
        assert r["implied_offset_ev"] == pytest.approx(r["bias_ev"] / (1 - k), rel=1e-3)
    else:  # a pure hold predictor never moves: no finite fixed point
        assert r["bias_ev"] == pytest.approx(0.0, abs=1e-4) and math.isinf(r["implied_offset_ev"])


def test_no_perturbation_gives_no_slope(validation):
    same = validation.__class__(**{**validation.__dict__,
                                   "gain_norm": validation.gain_norm.clone(),
                                   "exposure_norm": validation.exposure_norm.clone()})
    i1, i2 = single_camera_pairs(same)
    same.gain_norm[i2] = same.gain_norm[i1]
    same.exposure_norm[i2] = same.exposure_norm[i1]
    r = camera_follow(Mix(0.5), same)
    assert r["n_used"] == 0 and math.isnan(r["follow"]) and math.isnan(r["implied_offset_ev"])
