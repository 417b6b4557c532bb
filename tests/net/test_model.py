"""The paper's network: authors' sizes at 224, computed last kernel at other sizes, config validation."""

from __future__ import annotations

import pytest
import torch

from expoctl.errors import ConfigError
from expoctl.net.model import ExposureNet, ModelConfig, count_macs, count_parameters, min_input_size, scale_widths


def test_authors_sizes_at_224():
    cfg = ModelConfig()
    model = ExposureNet(cfg)
    convs = [m for m in model.modules() if isinstance(m, torch.nn.Conv2d)]
    assert [(c.in_channels, c.out_channels, c.kernel_size) for c in convs] == [
        (15, 30, (5, 5)), (30, 60, (3, 3)), (60, 120, (3, 3)), (120, 240, (7, 7))]
    fcs = [m for m in model.modules() if isinstance(m, torch.nn.Linear)]
    assert [(f.in_features, f.out_features) for f in fcs] == [(240, 128), (128, 64), (64, 32), (32, 2)]
    # paper: ~1.55 M parameters, ~0.66 G multiply-adds per sample
    assert count_parameters(model) == 1_546_498
    assert count_macs(cfg) == 656_193_224
    assert sum(isinstance(m, torch.nn.Dropout) and m.p == 0.4 for m in model.modules()) == 7


@pytest.mark.parametrize("hw", [(224, 224), (128, 128), (96, 128), (55, 55)])
def test_any_size_reduces_to_one_by_one(hw):
    model = ExposureNet(ModelConfig(input_size=hw, conv_widths=(4, 4, 4, 8), fc_widths=(8, 8, 8))).eval()
    assert model.features(torch.zeros(2, 15, *hw)).shape == (2, 8, 1, 1)
    assert model(torch.zeros(2, 15, *hw)).shape == (2, 2)


def test_macs_match_layer_shapes_at_128():
    cfg = ModelConfig(input_size=(128, 128))
    # 124→41 (conv5, pool3), 39→13, 11→3, conv 3×3 → 1
    expected = (124 * 124 * 30 * 15 * 25 + 39 * 39 * 60 * 30 * 9 + 11 * 11 * 120 * 60 * 9 + 240 * 120 * 9
                + 240 * 128 + 128 * 64 + 64 * 32 + 32 * 2)
    assert count_macs(cfg) == expected


def test_config_validation_names_keys():
    assert min_input_size((5, 3, 3), 3) == 55
    with pytest.raises(ConfigError, match="model.input_size"):
        ModelConfig.from_dict({"input_size": 54})
    with pytest.raises(ConfigError, match="model.dropout"):
        ModelConfig.from_dict({"dropout": 1.0})
    with pytest.raises(ConfigError, match="model.widths"):
        ModelConfig.from_dict({"widths": [1]})
    assert ModelConfig.from_dict({"input_size": [96, 128]}).input_size == (96, 128)
    with pytest.raises(ConfigError, match="model.exposure_scale"):
        ModelConfig.from_dict({"exposure_scale": "ln"})
    assert ModelConfig.from_dict({"exposure_scale": "log"}).exposure_scale == "log"


def test_value_that_does_not_convert_names_its_own_key_and_every_problem_is_reported():
    with pytest.raises(ConfigError) as exc:
        ModelConfig.from_dict({"dropout": "abc", "conv_widths": "30", "input_size": "big", "pool": 0})
    assert exc.value.problems == [  # one reader (config_reader.read_config): in field order, then the rules
        ("model.input_size", "must be a size in pixels or [height, width], got 'big'"),
        ("model.conv_widths", "must be a non-empty list of finite numbers, got '30'"),
        ("model.dropout", "must be a finite number, got 'abc'"),
        ("model.conv_kernels", "kernels and pool must be ≥ 1"),
    ]
    with pytest.raises(ConfigError) as exc:
        ModelConfig.from_dict({"conv_widths": [30, 60.5, 120, 240]})
    assert exc.value.problems == [("model.conv_widths", "must be a list of integers, got [30, 60.5, 120, 240]")]


def test_residual_output_starts_as_the_hold_predictor():
    """output=residual: an untrained net returns frame t's own normalised settings (channels 3, 4), whatever else
    the frames show; training then moves it away only through the head."""
    cfg = ModelConfig(input_size=(24, 24), conv_kernels=(3, 3, 3), pool=2, conv_widths=(4, 4, 4, 4),
                      fc_widths=(4, 4, 4), output="residual")
    net = ExposureNet(cfg).eval()
    x = torch.rand(5, 15, 24, 24)
    x[:, 3] = torch.tensor([0.1, 0.2, 0.3, 0.4, 0.5])[:, None, None]
    x[:, 4] = torch.tensor([0.9, 0.8, 0.7, 0.6, 0.5])[:, None, None]
    with torch.no_grad():
        y = net(x)
    assert torch.equal(y, x[:, 3:5, 0, 0])
    with pytest.raises(ConfigError, match="model.output"):
        ModelConfig.from_dict({"output": "delta"})


def test_scale_widths():
    cfg = scale_widths(ModelConfig(), 0.5)
    assert cfg.conv_widths == (15, 30, 60, 120) and cfg.fc_widths == (64, 32, 16)
