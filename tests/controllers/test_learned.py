"""The learned controller: history of three frames, clamping/unscaling, torch and ONNX backends, registry."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.controllers.base import Settings
from expoctl.controllers.learned import LearnedController, exposure_first, make_learned, read_learned_params
from expoctl.controllers.registry import make_controller
from expoctl.errors import ConfigError
from expoctl.net.model import ExposureNet, ModelConfig
from expoctl.net.checkpoint import CHECKPOINT_FORMAT, export_onnx

CFG = ModelConfig(input_size=(24, 24), conv_kernels=(3, 3, 3), pool=2, conv_widths=(4, 4, 4, 4), fc_widths=(4, 4, 4))


class Fixed(nn.Module):
    """Stands in for the network: returns the given normalised outputs and records its inputs."""

    def __init__(self, out):
        super().__init__()
        self.out = torch.tensor([out], dtype=torch.float32)
        self.inputs = []

    def forward(self, x):
        self.inputs.append(x.clone())
        return self.out.expand(x.shape[0], 2)


def _frame(value: int, hw=(48, 64)) -> np.ndarray:
    return np.full((*hw, 3), value, np.uint8)


@pytest.mark.parametrize("out, expected", [
    ((0.5, 0.0), (0.5 * GAIN_DB_MAX, EXPOSURE_US_MIN)),
    ((-0.3, 1.7), (GAIN_DB_MIN, EXPOSURE_US_MAX)),  # clamped to [0, 1] before unscaling
    ((1.2, 0.5), (GAIN_DB_MAX, EXPOSURE_US_MIN + 0.5 * (EXPOSURE_US_MAX - EXPOSURE_US_MIN))),
])
def test_clamps_and_unscales(out, expected):
    ctrl = LearnedController(Fixed(out), store_hw=(24, 32), input_hw=(24, 24))
    ctrl.reset(Settings(0.0, 1000.0))
    s = ctrl.update(_frame(10), Settings(0.0, 1000.0))
    assert (s.gain_db, s.exposure_us) == pytest.approx(expected)


def test_log_scaled_model_unscales_and_feeds_planes_in_ev():
    net = Fixed((0.0, 0.5))
    net.cfg = ModelConfig(**{**CFG.__dict__, "exposure_scale": "log"})  # as ExposureNet carries it
    ctrl = LearnedController(net, store_hw=(24, 32), input_hw=(24, 24))
    assert ctrl.exposure_scale == "log"
    ctrl.reset(Settings(0.0, 150.0))
    s = ctrl.update(_frame(10), Settings(0.0, 150.0))
    assert s.exposure_us == pytest.approx((EXPOSURE_US_MIN * EXPOSURE_US_MAX) ** 0.5)  # mid-range in EV
    # 150 µs is one stop above the minimum: plane value 1 / 8.64
    assert float(net.inputs[0][0, 4, 0, 0]) == pytest.approx(1 / np.log2(EXPOSURE_US_MAX / EXPOSURE_US_MIN), rel=1e-6)


@pytest.mark.parametrize("given, expected", [
    ((12.0, 500.0), (0.0, 500.0 * 10 ** 0.6)),          # all 12 dB fit into exposure: 1990.5 µs at 0 dB
    ((12.0, 15000.0), (12.0 - 20 * np.log10(2.0), 30000.0)),  # exposure caps at 30 ms, 6.02 dB stays gain
    ((0.0, 800.0), (0.0, 800.0)),                        # nothing to move
])
def test_exposure_first_keeps_the_exposure_product(given, expected):
    s = exposure_first(Settings(*given))
    assert (s.gain_db, s.exposure_us) == pytest.approx(expected)
    product = lambda g, e: e * 10 ** (g / 20)  # noqa: E731
    assert product(s.gain_db, s.exposure_us) == pytest.approx(product(*given))


def test_allocation_option_applies_to_the_output_and_is_validated():
    ctrl = LearnedController(Fixed((0.4, 0.0)), store_hw=(24, 32), input_hw=(24, 24), allocation="exposure_first")
    ctrl.reset(Settings(0.0, 1000.0))
    s = ctrl.update(_frame(10), Settings(0.0, 1000.0))
    # the network asked for 12 dB at 75 µs: the same product at 0 dB is 75 · 10^0.6 µs
    assert (s.gain_db, s.exposure_us) == pytest.approx((0.0, EXPOSURE_US_MIN * 10 ** 0.6))
    with pytest.raises(ConfigError, match="controllers.learned.allocation"):
        LearnedController(Fixed((0.0, 0.0)), store_hw=(24, 32), input_hw=(24, 24), allocation="gain_first")


def test_keeps_three_frame_history_and_repeats_at_start():
    net = Fixed((0.1, 0.1))
    ctrl = LearnedController(net, store_hw=(24, 32), input_hw=(24, 24))
    ctrl.reset(Settings(0.0, 100.0))
    for i in range(4):
        ctrl.update(_frame(10 * (i + 1)), Settings(float(i), 100.0 * (i + 1)))
    red = [[round(float(x[0, 5 * k, 0, 0]) * 255) for k in range(3)] for x in net.inputs]  # R of t, t−1, t−2
    assert red == [[10, 10, 10], [20, 10, 10], [30, 20, 10], [40, 30, 20]]
    gain = [float(x[0, 3 + 5 * k, 0, 0]) * GAIN_DB_MAX for k in range(3) for x in net.inputs[-1:]]
    assert gain == pytest.approx([3.0, 2.0, 1.0])
    ctrl.reset(Settings(0.0, 100.0))  # a new sequence forgets the old frames
    ctrl.update(_frame(99), Settings(0.0, 100.0))
    assert [round(float(net.inputs[-1][0, 5 * k, 0, 0]) * 255) for k in range(3)] == [99, 99, 99]


def test_checkpoint_backends_agree_and_registry(tmp_path):
    torch.manual_seed(0)
    model = ExposureNet(CFG).eval()
    for m in model.modules():  # non-trivial BN statistics so the outputs are not all alike
        if isinstance(m, (nn.BatchNorm1d, nn.BatchNorm2d)):
            m.running_mean.uniform_(-0.2, 0.2)
    ckpt = {"format": CHECKPOINT_FORMAT, "model_config": CFG.to_dict(), "state_dict": model.state_dict(),
            "store_hw": [32, 40], "input_hw": [24, 24]}
    torch.save(ckpt, tmp_path / "controller.pt")
    export_onnx(model, tmp_path / "controller.onnx")
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (120, 160, 3), dtype=np.uint8) for _ in range(5)]
    _run_backends(tmp_path, frames)  # "learned" is in the registry from the start (built lazily: torch, checkpoint)


def _run_backends(tmp_path, frames):
    results = {}
    for backend in ("torch", "onnx"):
        ctrl = make_controller("learned", {"checkpoint": str(tmp_path / "controller.pt"), "backend": backend,
                                           "num_threads": 1})
        assert ctrl.name == "learned" and ctrl.store_hw == (32, 40)
        ctrl.reset(Settings(5.0, 2000.0))
        applied, outs = Settings(5.0, 2000.0), []
        for f in frames:
            applied = ctrl.update(f, applied)
            outs.append((applied.gain_db, applied.exposure_us))
        results[backend] = np.array(outs)
    # 1e-4 in normalised units, in physical units
    assert np.allclose(results["torch"][:, 0], results["onnx"][:, 0], atol=1e-4 * GAIN_DB_MAX)
    assert np.allclose(results["torch"][:, 1], results["onnx"][:, 1], atol=1e-4 * EXPOSURE_US_MAX)
    with pytest.raises(ConfigError, match="controllers.learned.backend"):
        make_controller("learned", {"checkpoint": str(tmp_path / "controller.pt"), "backend": "tensorrt"})
    with pytest.raises(ConfigError, match="controllers.learned.weights"):
        make_learned({"weights": "x"})
    # latency_frames 2: the same commands, each one frame later (the first frame keeps the initial settings)
    late = make_learned({"checkpoint": str(tmp_path / "controller.pt"), "latency_frames": 2})
    assert late.name == "learned"
    late.reset(Settings(5.0, 2000.0))
    applied, outs = Settings(5.0, 2000.0), []
    for f, prompt in zip(frames, [Settings(5.0, 2000.0)] + [Settings(*o) for o in results["torch"][:-1]]):
        applied = late.update(f, prompt)  # fed the settings the on-time run saw, so the network's inputs agree
        outs.append((applied.gain_db, applied.exposure_us))
    assert outs[0] == (5.0, 2000.0) and np.allclose(outs[1:], results["torch"][:-1])
    for bad in (0, 1.5, "2"):
        with pytest.raises(ConfigError, match="controllers.learned.latency_frames"):
            make_learned({"checkpoint": str(tmp_path / "controller.pt"), "latency_frames": bad})


def test_params_are_checked_without_a_checkpoint():
    """The compose stage checks controllers.learned before any network exists: no file is opened."""
    assert read_learned_params({"checkpoint": "/nonexistent/controller.pt", "latency_frames": 2}) == {
        "path": "/nonexistent/controller.pt", "backend": "torch", "num_threads": 1, "allocation": "network",
        "latency_frames": 2}
    with pytest.raises(ConfigError) as exc:
        read_learned_params({"backend": "tensorrt", "allocation": "x", "latency_frames": 0, "weights": "w"})
    assert [k for k, _ in exc.value.problems] == ["controllers.learned.backend", "controllers.learned.allocation",
                                                  "controllers.learned.latency_frames", "controllers.learned.weights"]
