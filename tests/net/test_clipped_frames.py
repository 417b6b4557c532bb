"""The clipped-frame prior: settings in EV, the draw's range, the hinge's value and its effect on a trained network."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from expoctl.camera.ranges import exposure_to_norm, gain_to_norm
from expoctl.errors import ConfigError
from expoctl.net.clipped_frames import (EXPOSURE_RANGE_EV, RANGE_EV, clipped_frame_loss, draw_settings, settings_ev,
                                        uniform_frame_steps)
from expoctl.net.dataset import load_sample_sets_from_files
from expoctl.net.model import ModelConfig
from expoctl.net.train import TrainConfig, fit
from tests.support.synthetic_data import make_synthetic_dataset


@pytest.mark.parametrize("scale", ["log", "linear"])
def test_settings_ev_is_the_exposure_product(scale):
    g = torch.tensor(gain_to_norm(np.array([0.0, 6.0206, 30.0])), dtype=torch.float64)
    e = torch.tensor(exposure_to_norm(np.array([75.0, 150.0, 30000.0]), scale), dtype=torch.float64)
    torch.testing.assert_close(settings_ev(g, e, scale), torch.tensor([0.0, 2.0, RANGE_EV], dtype=torch.float64))
    # outputs are clamped as deployed: below 0 dB / 75 µs counts as 0 dB / 75 µs
    assert float(settings_ev(torch.tensor([-0.5]), torch.tensor([-0.2]), scale)) == 0.0


def test_draw_stays_where_the_margin_can_be_stepped():
    gen = torch.Generator().manual_seed(0)
    g, e = draw_settings(2000, 0.5, RANGE_EV - 1.0, "log", gen)
    ev = settings_ev(g, e, "log")
    assert len(g) == 2000 and float(ev.min()) >= 0.5 - 1e-5 and float(ev.max()) <= RANGE_EV - 1.0 + 1e-5
    assert float(g.min()) >= 0 and float(g.max()) <= 1 and float(e.min()) >= 0 and float(e.max()) <= 1


class Constant(torch.nn.Module):
    """Outputs its input's frame-t settings plus a fixed step (in normalised exposure units, log scale)."""

    def __init__(self, step_ev: float):
        super().__init__()
        self.step = step_ev / EXPOSURE_RANGE_EV

    def forward(self, x):
        return torch.stack([x[:, 3, 0, 0], x[:, 4, 0, 0] + self.step], dim=1)


def test_hinge_is_zero_only_beyond_the_margins():
    gen = torch.Generator().manual_seed(1)
    # a network that holds its settings: white misses by m_white, black by m_black (where the exposure can move)
    hold = float(clipped_frame_loss(Constant(0.0), 64, (0.25, 0.5), (8, 8), "log", gen))
    assert 0 < hold <= (0.25 + 0.5) / 2 / EXPOSURE_RANGE_EV + 1e-6
    # stepping darker by 1 EV everywhere: white satisfied (where exposure time has room), black costs 1.5 EV
    dark = float(clipped_frame_loss(Constant(-1.0), 64, (0.25, 0.5), (8, 8), "log", gen))
    assert dark > hold
    steps = uniform_frame_steps(Constant(-1.0), 255, (8, 8), "log")
    assert float(steps[0, 0]) == pytest.approx(-1.0, abs=1e-5)  # 0 dB, 200 µs: room to go 1 EV darker


def test_config_names_bad_prior_values():
    with pytest.raises(ConfigError) as err:
        TrainConfig.from_dict({"clipped_frame_weight": -1, "clipped_frame_samples": 0,
                               "clipped_frame_margin_ev": [0.2, 5.0]})
    for key in ("clipped_frame_weight", "clipped_frame_samples", "clipped_frame_margin_ev"):
        assert f"train.{key}" in str(err.value)


TINY = ModelConfig(input_size=(32, 32), conv_kernels=(3, 3, 3), pool=2, conv_widths=(8, 16, 16, 32),
                   fc_widths=(16, 8, 8), dropout=0.1, exposure_scale="log", output="residual")


def test_the_prior_makes_white_step_darker_and_black_brighter(tmp_path):
    p = make_synthetic_dataset(tmp_path, n_sequences=4, n_frames=12, hw=(32, 32), seed=0)
    sets = load_sample_sets_from_files(p["samples"], p["frames"], p["images_dir"], 32, exposure_scale="log")
    base = dict(lr=3e-3, batch_size=16, epochs=6, patience=10, num_threads=1)
    prior = fit(TINY, TrainConfig(**base, clipped_frame_weight=20.0, clipped_frame_samples=8), sets["train"],
                sets["validation"], seed=0).metrics
    # no absorbing state left on the grid: darker on white, brighter on black, at every setting
    assert prior["white_step_max_ev"] < 0 and prior["black_step_min_ev"] > 0
    plain = fit(TINY, TrainConfig(**base), sets["train"], sets["validation"], seed=0).metrics
    # the synthetic data hold bright frames with darker labels but no black ones: without the prior, a black frame
    # at some setting is an absorbing state (the same seed, batches and samples)
    assert plain["black_step_min_ev"] < 0
