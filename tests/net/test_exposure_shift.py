"""Synthetic over-exposure: codes re-encoded as the camera's response would, settings moved exposure first, the
headroom respected, the draw, the config and its use in training."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from expoctl.camera.ranges import exposure_to_norm, gain_to_norm
from expoctl.camera.response import Response
from expoctl.errors import ConfigError
from expoctl.net.dataset import load_sample_sets_from_files
from expoctl.net.exposure_shift import DB_PER_EV, MAX_SHIFT_EV, ExposureShift, draw_shifts, encoding_thresholds
from expoctl.net.model import ModelConfig
from expoctl.net.train import TrainConfig, fit
from tests.support.synthetic_data import make_synthetic_dataset

RESPONSES = {
    "srgb": Response(),
    "per_channel": Response("gamma", (1.8, 2.2, 2.6), pedestal=(0.02, -0.01, 0.0), white_balance=(1.3, 1.0, 0.8)),
}


def _planes(gain_db, exposure_us, scale="log"):
    g = torch.tensor(gain_to_norm(np.asarray(gain_db, np.float64)), dtype=torch.float32)
    e = torch.tensor(exposure_to_norm(np.asarray(exposure_us, np.float64), scale), dtype=torch.float32)
    return g, e


@pytest.mark.parametrize("name", sorted(RESPONSES))
def test_thresholds_encode_exactly_as_the_response(name):
    response = RESPONSES[name]
    thresholds = torch.from_numpy(encoding_thresholds(response)[1:])
    x = np.random.default_rng(0).random((20000, 3))
    x[:10] = 1.0  # full scale: with a white balance < 1 the blue channel's top code is below 255
    ours = np.stack([torch.bucketize(torch.from_numpy(x[:, c].copy()), thresholds[:, c].contiguous(), right=True).numpy()
                     for c in range(3)], axis=1)
    np.testing.assert_array_equal(ours, response.linear_to_8bit(x))


@pytest.mark.parametrize("name", sorted(RESPONSES))
def test_frames_are_the_brighter_camera_image(name):
    response = RESPONSES[name]
    rng = np.random.default_rng(1)
    frames = torch.from_numpy(rng.integers(0, 256, (3, 3, 3, 8, 8), dtype=np.uint8))
    g, e = _planes(np.zeros((3, 3)), np.full((3, 3), 1000.0))
    k = torch.tensor([0.0, 1.5, 4.0])
    out, _, _ = ExposureShift(response, "log").apply(frames, g, e, k)
    assert torch.equal(out[0], frames[0])  # no shift: untouched
    for i in (1, 2):
        hwc = frames[i].permute(0, 2, 3, 1).numpy()  # (3 frames, h, w, RGB)
        expected = response.linear_to_8bit(np.minimum(response.uint8_to_linear(hwc).astype(np.float64)
                                                      * 2.0 ** float(k[i]), 1.0))
        np.testing.assert_array_equal(out[i].permute(0, 2, 3, 1).numpy(), expected)


def test_linear_response_doubles_codes_per_ev_and_clips():
    frames = torch.full((1, 3, 3, 2, 2), 60, dtype=torch.uint8)
    frames[0, :, :, 1, 1] = 200
    g, e = _planes(np.zeros((1, 3)), np.full((1, 3), 1000.0))
    out, _, _ = ExposureShift(Response("linear"), "log").apply(frames, g, e, torch.tensor([1.0]))
    assert int(out[0, 0, 0, 0, 0]) == 120 and int(out[0, 0, 0, 1, 1]) == 255  # 2 × 200 clips at full scale


@pytest.mark.parametrize("scale", ["log", "linear"])
def test_settings_move_exposure_first_then_gain(scale):
    # frame t: 1 ms → 4 ms at 0 dB; frame t−1: 20 ms → 30 ms (the maximum), the remaining 2 − log2(1.5) EV on gain;
    # frame t−2: 2 ms at 6 dB keeps its gain and goes to 8 ms
    g, e = _planes([[0.0, 0.0, 6.0]], [[1000.0, 20000.0, 2000.0]], scale)
    frames = torch.zeros((1, 3, 3, 2, 2), dtype=torch.uint8)
    _, g2, e2 = ExposureShift(Response(), scale).apply(frames, g, e, torch.tensor([2.0]))
    exp_g, exp_e = _planes([[0.0, (2.0 - math.log2(1.5)) * DB_PER_EV, 6.0]], [[4000.0, 30000.0, 8000.0]], scale)
    torch.testing.assert_close(g2, exp_g, atol=1e-6, rtol=0)
    torch.testing.assert_close(e2, exp_e, atol=1e-6, rtol=0)


def test_shift_is_cut_to_the_camera_range():
    # 30 ms at 28 dB leaves (30 − 28) / 6.02 = 0.33 EV: the image brightens by that much, not by 6 EV
    g, e = _planes([[28.0, 0.0, 0.0]], [[30000.0, 1000.0, 1000.0]])
    frames = torch.full((1, 3, 3, 2, 2), 100, dtype=torch.uint8)
    shifter = ExposureShift(Response("linear"), "log")
    assert float(shifter.headroom_ev(g, e)[0]) == pytest.approx(2.0 / DB_PER_EV, rel=1e-5)
    out, g2, _ = shifter.apply(frames, g, e, torch.tensor([6.0]))
    assert float(g2[0, 0]) == pytest.approx(1.0)
    assert int(out[0, 0, 0, 0, 0]) == round(100 * 2 ** (2.0 / DB_PER_EV))  # 126, not clipped
    # at the top of the range nothing can brighten: the sample stays as it was
    g, e = _planes([[30.0] * 3], [[30000.0] * 3])
    out, g2, e2 = shifter.apply(frames, g, e, torch.tensor([3.0]))
    assert torch.equal(out, frames) and torch.equal(g2, g) and torch.equal(e2, e)


def test_an_exposure_below_the_network_range_is_not_clamped_first():
    # the sensor goes down to 19 µs, below the planes' 75 µs floor: 19 µs + 2 EV is 76 µs, not 300 µs
    g, e = _planes([[0.0] * 3], [[19.0] * 3])
    _, _, e2 = ExposureShift(Response(), "log").apply(torch.zeros((1, 3, 3, 2, 2), dtype=torch.uint8), g, e,
                                                      torch.tensor([2.0]))
    assert float(e2[0, 0]) == pytest.approx(float(exposure_to_norm(76.0, "log")), abs=1e-6)


def test_draw_shares_and_range():
    gen = torch.Generator().manual_seed(0)
    assert not draw_shifts(1000, 0.0, (0.0, 6.0), gen).any()
    k = draw_shifts(1000, 1.0, (2.0, 5.0), gen)
    assert float(k.min()) >= 2.0 and float(k.max()) <= 5.0
    n, p = 20000, 0.25
    share = float((draw_shifts(n, p, (1.0, 6.0), gen) > 0).float().mean())
    assert abs(share - p) < 5 * math.sqrt(p * (1 - p) / n)  # five binomial standard errors


def test_config_reports_every_bad_value():
    with pytest.raises(ConfigError) as err:
        TrainConfig.from_dict({"exposure_shift_probability": 1.5, "exposure_shift_ev": [-1.0, 2.0], "epsilon": 2})
    text = str(err.value)
    for key in ("train.exposure_shift_probability", "train.exposure_shift_ev", "train.epsilon"):
        assert key in text
    for bad in ([3.0, 1.0], [0.0, MAX_SHIFT_EV + 1], [0.0, float("nan")]):
        with pytest.raises(ConfigError, match="train.exposure_shift_ev"):
            TrainConfig.from_dict({"exposure_shift_ev": bad})
    with pytest.raises(ConfigError, match="train"):
        TrainConfig.from_dict({"exposure_shift_ev": "0 6"})
    assert TrainConfig.from_dict({"exposure_shift_ev": [1, 4]}).exposure_shift_ev == (1.0, 4.0)


TINY = ModelConfig(input_size=(32, 32), conv_kernels=(3, 3, 3), pool=2, conv_widths=(8, 16, 16, 32),
                   fc_widths=(16, 8, 8), dropout=0.1, exposure_scale="log", output="residual")


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    p = make_synthetic_dataset(tmp_path_factory.mktemp("syn"), n_sequences=4, n_frames=12, hw=(32, 32), seed=0)
    return load_sample_sets_from_files(p["samples"], p["frames"], p["images_dir"], 32, exposure_scale="log")


def test_training_with_shifts_needs_the_response_and_is_reproducible(sets):
    cfg = TrainConfig(lr=3e-3, batch_size=16, epochs=2, patience=5, num_threads=1, exposure_shift_probability=0.5)
    with pytest.raises(ConfigError, match="train.exposure_shift_probability"):
        fit(TINY, cfg, sets["train"], sets["validation"], seed=0)
    a = fit(TINY, cfg, sets["train"], sets["validation"], seed=0, response=Response())
    b = fit(TINY, cfg, sets["train"], sets["validation"], seed=0, response=Response())
    plain = fit(TINY, TrainConfig(lr=3e-3, batch_size=16, epochs=2, patience=5, num_threads=1),
                sets["train"], sets["validation"], seed=0)
    for name, w in a.model.state_dict().items():
        assert torch.equal(w, b.model.state_dict()[name]), name
    assert any(not torch.equal(w, plain.model.state_dict()[n]) for n, w in a.model.state_dict().items()
               if w.dtype.is_floating_point)
    # camera-consistency pairs get their anchors' shifts (one batch layout, also with shifts)
    paired = TrainConfig(lr=3e-3, batch_size=16, epochs=1, patience=5, num_threads=1, exposure_shift_probability=0.5,
                         consistency_weight=0.5)
    assert math.isfinite(fit(TINY, paired, sets["train"], sets["validation"], seed=0, response=Response())
                         .metrics["val_loss"])


def test_shifted_batch_needs_a_matching_shifter(sets):
    data = sets["train"]
    k = torch.tensor([1.0, 0.0])
    with pytest.raises(ValueError, match="exposure scale"):
        data.batch([0, 1], shift_ev=k)
    with pytest.raises(ValueError, match="exposure scale"):
        data.batch([0, 1], shift_ev=k, shifter=ExposureShift(Response(), "linear"))
    x, _ = data.batch([0, 1], shift_ev=k, shifter=ExposureShift(Response(), "log"))
    x0, _ = data.batch([0, 1])
    assert torch.equal(x[1], x0[1]) and (x[0, :3] >= x0[0, :3]).all() and not torch.equal(x[0], x0[0])
