"""A prior for clipped frames: on an all-white input the next setting must be darker, on an all-black one brighter.

Why: a frame with every pixel clipped says only "overexposed", whatever the settings planes say; a black one only
"underexposed". A network whose step there is ≥ 0 (white) or ≤ 0 (black) has an absorbing state in closed loop. The
training data hardly hold such frames, so the step there is left to the draw of training: over eleven replicate
networks the four that fail the saturation probe step +0.02 to +0.23 EV on an all-white frame next to the probe's
start, the seven that pass −0.12 to −0.85 EV (docs/runs/calibrated_seeds/README.md, `benchmarks/archive/white_step.py`). Labelled
brightened samples (`expoctl.net.exposure_shift`) did not fix the step. This term states the physics directly.

Loss (added to the L1 loss with weight λ = `train.clipped_frame_weight`): for uniform frames (the three input frames
all code 255, or all code 0) at settings drawn log-uniformly over the camera's range (exposure time 75 µs … 30 ms, gain
0 … 30 dB, each independently), the hinge max(0, step + m_white) on white and max(0, m_black − step) on black, with
step = output − input exposure product in EV (outputs clamped to the range, as deployed: at 0 dB only the exposure
time can go lower). Settings from which the margin cannot be stepped (white within m_white of the darkest setting,
black within m_black of the brightest) are not drawn. The hinge is divided by the exposure range in EV (8.64), so
one EV weighs what it does in the log-scaled L1 loss. The margins are the real camera's measured AE limits
(docs/calibration.md): it darkened by at most 0.178 EV per frame at the recorded exit and brightened by 0.51 EV at
the entry; the network should at least keep up with the camera's own AE on a frame that shows nothing.

The prior's frames go through the model in eval mode (batch norm with its running statistics, no dropout): the term
shapes the deployed function, and uniform frames do not enter the batch statistics of the real samples.
"""

from __future__ import annotations

import math

import torch

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.net.exposure_shift import DB_PER_EV, MAX_SHIFT_EV
from expoctl.net.preprocess import N_FRAMES, assemble_input

_LOG2_MIN, _LOG2_MAX = math.log2(EXPOSURE_US_MIN), math.log2(EXPOSURE_US_MAX)
RANGE_EV = MAX_SHIFT_EV  # the whole settings range, 13.6 EV
EXPOSURE_RANGE_EV = _LOG2_MAX - _LOG2_MIN  # 8.64 EV: one unit of the log exposure scale


def settings_ev(gain_norm: torch.Tensor, exposure_norm: torch.Tensor, exposure_scale: str) -> torch.Tensor:
    """Normalised settings (clamped to [0, 1] as deployed) → the exposure product in EV above (75 µs, 0 dB);
    differentiable inside the range."""
    g = gain_norm.clamp(0.0, 1.0) * (GAIN_DB_MAX - GAIN_DB_MIN) / DB_PER_EV
    e = exposure_norm.clamp(0.0, 1.0)
    if exposure_scale == "log":
        return g + e * EXPOSURE_RANGE_EV
    if exposure_scale == "linear":
        return g + torch.log2(EXPOSURE_US_MIN + e * (EXPOSURE_US_MAX - EXPOSURE_US_MIN)) - _LOG2_MIN
    raise ValueError(f"unknown exposure scale {exposure_scale!r}")


def draw_settings(n: int, lo_ev: float, hi_ev: float, exposure_scale: str,
                  generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """n settings, exposure time log-uniform and gain uniform in dB, kept to a product within [lo_ev, hi_ev] EV above
    the darkest setting (rejection, then a redraw): (gain_norm, exposure_norm) (n,) float32 in `exposure_scale`."""
    from expoctl.camera.ranges import exposure_to_norm

    gain_n, exp_n = torch.empty(0), torch.empty(0)
    while len(gain_n) < n:
        g = torch.rand(4 * n, generator=generator)
        log2e = _LOG2_MIN + torch.rand(4 * n, generator=generator) * EXPOSURE_RANGE_EV
        ev = g * (GAIN_DB_MAX - GAIN_DB_MIN) / DB_PER_EV + log2e - _LOG2_MIN
        keep = (ev >= lo_ev) & (ev <= hi_ev)
        e = torch.from_numpy(exposure_to_norm(torch.exp2(log2e[keep]).double().numpy(), exposure_scale)).float()
        gain_n, exp_n = torch.cat([gain_n, g[keep]]), torch.cat([exp_n, e])
    return gain_n[:n], exp_n[:n]


def clipped_frame_loss(model: torch.nn.Module, n_per_side: int, margins_ev: tuple[float, float], hw: tuple[int, int],
                       exposure_scale: str, generator: torch.Generator) -> torch.Tensor:
    """The prior's hinge (module doc) over n_per_side white and n_per_side black uniform inputs, model in eval mode
    for the pass (restored after)."""
    m_white, m_black = margins_ev
    gw, ew = draw_settings(n_per_side, m_white, RANGE_EV, exposure_scale, generator)
    gb, eb = draw_settings(n_per_side, 0.0, RANGE_EV - m_black, exposure_scale, generator)
    gain, exposure = torch.cat([gw, gb]), torch.cat([ew, eb])
    frames = torch.zeros((2 * n_per_side, N_FRAMES, 3, *hw), dtype=torch.uint8)
    frames[:n_per_side] = 255
    x = assemble_input(frames, gain.view(-1, 1).expand(-1, N_FRAMES).contiguous(),
                       exposure.view(-1, 1).expand(-1, N_FRAMES).contiguous())
    was_training = model.training
    model.eval()
    try:
        out = model(x)
    finally:
        model.train(was_training)
    step = settings_ev(out[:, 0], out[:, 1], exposure_scale) - settings_ev(gain, exposure, exposure_scale)
    white = torch.relu(step[:n_per_side] + m_white)
    black = torch.relu(m_black - step[n_per_side:])
    return torch.cat([white, black]).mean() / EXPOSURE_RANGE_EV


GRID_GAINS_DB = (0.0, 6.0, 12.0, 18.0, 24.0)
GRID_EXPOSURES_US = (200.0, 500.0, 2000.0, 5000.0, 10000.0, 20000.0, 30000.0)


@torch.no_grad()
def uniform_frame_steps(model: torch.nn.Module, code: int, hw: tuple[int, int], exposure_scale: str,
                        gains_db=GRID_GAINS_DB, exposures_us=GRID_EXPOSURES_US) -> torch.Tensor:
    """(len(gains_db), len(exposures_us)) EV: the model's step (eval mode) on uniform frames of `code` (255: all
    white, 0: all black) at each setting of the grid; outputs clamped as deployed."""
    from expoctl.camera.ranges import exposure_to_norm, gain_to_norm

    g = torch.tensor(gains_db, dtype=torch.float64).view(-1, 1).expand(-1, len(exposures_us)).reshape(-1)
    e = torch.tensor(exposures_us, dtype=torch.float64).view(1, -1).expand(len(gains_db), -1).reshape(-1)
    gn = torch.from_numpy(gain_to_norm(g.numpy())).float()
    en = torch.from_numpy(exposure_to_norm(e.numpy(), exposure_scale)).float()
    frames = torch.full((len(g), N_FRAMES, 3, *hw), code, dtype=torch.uint8)
    was_training = model.training
    model.eval()
    try:
        out = model(assemble_input(frames, gn.view(-1, 1).expand(-1, N_FRAMES).contiguous(),
                                   en.view(-1, 1).expand(-1, N_FRAMES).contiguous()))
    finally:
        model.train(was_training)
    step = settings_ev(out[:, 0].double(), out[:, 1].double(), exposure_scale) - settings_ev(gn.double(), en.double(),
                                                                                          exposure_scale)
    return step.view(len(gains_db), len(exposures_us))
