"""One preprocessing path: the dataset (training) and the learned controller (deployment) build identical inputs."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import torch

from expoctl.camera.ranges import exposure_to_norm, gain_to_norm
from expoctl.controllers.base import Settings
from expoctl.controllers.learned import LearnedController
from expoctl.net.dataset import load_sample_sets
from expoctl.net.model import ExposureNet, ModelConfig
from expoctl.net.preprocess import CHANNEL_NAMES, assemble_input, prepare_frame

FULL_HW = (96, 128)  # camera resolution
STORE_HW = (32, 48)  # image-store resolution (ingest)
INPUT_HW = (24, 36)  # network input, differs from the store: exercises the second resize


def _camera_frames(n: int) -> list[np.ndarray]:
    rng = np.random.default_rng(3)
    return [rng.integers(0, 256, (*FULL_HW, 3), dtype=np.uint8) for _ in range(n)]


def test_channel_order_and_scaling():
    frames = torch.zeros(1, 3, 3, 2, 2, dtype=torch.uint8)
    for f in range(3):
        for c in range(3):
            frames[0, f, c] = 10 * f + c + 1
    x = assemble_input(frames, torch.tensor([[0.1, 0.2, 0.3]]), torch.tensor([[0.4, 0.5, 0.6]]))
    assert x.shape == (1, 15, 2, 2) and x.dtype == torch.float32
    expected = []
    for f in range(3):
        expected += [(10 * f + c + 1) / 255 for c in range(3)] + [0.1 * (f + 1), 0.4 + 0.1 * f]
    assert torch.allclose(x[0, :, 0, 0], torch.tensor(expected))
    assert (x[0] == x[0, :, :1, :1]).all()  # every channel is spatially constant here
    assert CHANNEL_NAMES[:5] == ("R_t", "G_t", "B_t", "gain_t", "exposure_t") and CHANNEL_NAMES[-1] == "exposure_t-2"


def test_prepare_frame_reproduces_ingest_then_resizes():
    img = _camera_frames(1)[0]
    ingest = cv2.resize(img, (STORE_HW[1], STORE_HW[0]), interpolation=cv2.INTER_AREA)
    assert np.array_equal(prepare_frame(img, STORE_HW, STORE_HW), ingest)
    twice = cv2.resize(ingest, (INPUT_HW[1], INPUT_HW[0]), interpolation=cv2.INTER_AREA)
    assert np.array_equal(prepare_frame(img, STORE_HW, INPUT_HW), twice)
    assert np.array_equal(prepare_frame(ingest, STORE_HW, INPUT_HW), twice)  # stored frames: first step is a no-op


def test_training_and_deployment_inputs_identical(tmp_path):
    """Ingest-style store → dataset tensor == controller tensor from the full-size camera frames."""
    cams = _camera_frames(3)
    settings = [Settings(3.5, 1200.0), Settings(0.0, 30000.0), Settings(12.25, 75.0)]  # frames 0, 1, 2
    store = np.stack([np.stack([cv2.resize(im, (STORE_HW[1], STORE_HW[0]), interpolation=cv2.INTER_AREA)] * 2)
                      for im in cams])
    np.save(tmp_path / "s.npy", store)
    frames = pd.DataFrame([dict(sequence="s", frame_id=t, camera=c, gain_db=settings[t].gain_db,
                                exposure_us=settings[t].exposure_us, image_index=t)
                           for t in range(3) for c in (1, 2)])
    samples = pd.DataFrame([dict(sample_id=0, sequence="s", frame_id=2, cam_t=1, cam_t1=2, cam_t2=1,
                                 target_gain_norm=0.5, target_exposure_norm=0.5, split="train")])
    x_train, _ = load_sample_sets(samples, frames, tmp_path, INPUT_HW, splits=("train",))["train"].batch([0])

    cfg = ModelConfig(input_size=INPUT_HW, conv_kernels=(3, 3, 3), pool=2, conv_widths=(4, 4, 4, 4),
                      fc_widths=(4, 4, 4))
    ctrl = LearnedController(ExposureNet(cfg), STORE_HW, INPUT_HW)
    ctrl.reset(settings[0])
    for t in range(3):
        x_deploy = ctrl.network_input(cams[t], settings[t])
    assert x_deploy.dtype == x_train.dtype and x_deploy.shape == x_train.shape == (1, 15, *INPUT_HW)
    assert torch.equal(x_deploy, x_train)
    # frame t's planes carry its own settings (paper bug 1: never parsed from paths)
    assert float(x_train[0, 3, 0, 0]) == np.float32(gain_to_norm(12.25))
    assert float(x_train[0, 14, 0, 0]) == np.float32(exposure_to_norm(1200.0))
