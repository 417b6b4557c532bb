"""How much of the scene a network reads from the image, and the closed-loop offset that implies (open-loop probe).

At each labelled time step the samples c111 (all three frames from camera 1) and c222 (all from camera 2) share one
label: the best settings for frame t+1 do not depend on which camera's frames the network looks at. Their inputs
differ: camera 2's settings are perturbed, and its images are correspondingly brighter or darker. A network that
reads the scene gives both the same output; one that holds its input settings moves its output with them.

  follow   least-squares slope of (output EV, c222 − c111) on (input EV at t, c222 − c111), over the time steps
           whose two inputs differ by more than `min_input_difference_ev`: 0 = reads the scene, 1 = holds the
           settings (an untrained residual network)
  bias     median (output − input) EV of the c111 samples: the step it takes from the reference camera's state
  target   median (label − input) EV of the same samples: the step the labels ask for

In closed loop the network's input is its own last output. Linearised around the reference camera's state s_ref,
output(s) ≈ s_ref + bias + follow · (s − s_ref), whose fixed point lies offset = bias / (1 − follow) EV above s_ref:
a small per-frame bias is amplified when the network mostly follows its own settings. EV = log2(exposure / µs) +
gain / 6.02 dB, the exposure product in stops.
"""

from __future__ import annotations

import math

import numpy as np
from torch import nn

from expoctl.camera.ranges import exposure_value_ev, norm_to_exposure, norm_to_gain
from expoctl.net.dataset import SampleSet, predict

MIN_INPUT_DIFFERENCE_EV = 0.2  # pairs whose two cameras' settings differ less carry no slope information


def settings_ev(gain_norm, exposure_norm, exposure_scale: str) -> np.ndarray:
    """Normalised (gain, exposure) → exposure product in EV."""
    return exposure_value_ev(norm_to_gain(np.asarray(gain_norm, np.float64)),
                             norm_to_exposure(np.asarray(exposure_norm, np.float64), exposure_scale))


def single_camera_pairs(data: SampleSet) -> tuple[np.ndarray, np.ndarray]:
    """Rows of the c111 and c222 samples of every time step that has both, matched by time step."""
    one = np.flatnonzero(np.all(data.cameras == 1, axis=1))
    two = np.flatnonzero(np.all(data.cameras == 2, axis=1))
    step_one = {int(t): r for t, r in zip(data.time_step[one], one)}
    pairs = [(step_one[int(t)], r) for t, r in zip(data.time_step[two], two) if int(t) in step_one]
    if not pairs:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    i1, i2 = (np.array(v, np.int64) for v in zip(*pairs))
    return i1, i2


def camera_follow(model: nn.Module, data: SampleSet, batch_size: int = 256,
                  min_input_difference_ev: float = MIN_INPUT_DIFFERENCE_EV) -> dict:
    """The probe of the module doc on `data` (raw outputs, eval mode). `follow` and `implied_offset_ev` are NaN when
    fewer than two time steps have inputs that differ by more than `min_input_difference_ev`."""
    i1, i2 = single_camera_pairs(data)
    scale = data.exposure_scale

    def input_ev(rows):
        return settings_ev(data.gain_norm[rows, 0].numpy(), data.exposure_norm[rows, 0].numpy(), scale)

    o1, o2 = predict(model, data, batch_size, i1), predict(model, data, batch_size, i2)
    out1, out2 = settings_ev(o1[:, 0], o1[:, 1], scale), settings_ev(o2[:, 0], o2[:, 1], scale)
    in1, in2 = input_ev(i1), input_ev(i2)
    target = settings_ev(data.targets[i1, 0].numpy(), data.targets[i1, 1].numpy(), scale)
    d_in, d_out = in2 - in1, out2 - out1
    use = np.abs(d_in) > min_input_difference_ev
    follow = float(np.polyfit(d_in[use], d_out[use], 1)[0]) if use.sum() >= 2 else math.nan
    bias = float(np.median(out1 - in1)) if len(i1) else math.nan
    offset = (bias / (1.0 - follow) if follow < 1.0 else math.inf) if math.isfinite(follow) else math.nan
    return {"n_time_steps": int(len(i1)), "n_used": int(use.sum()), "follow": follow, "bias_ev": bias,
            "target_step_ev": float(np.median(target - in1)) if len(i1) else math.nan,
            "abs_error_c111_ev": float(np.median(np.abs(out1 - target))) if len(i1) else math.nan,
            "abs_error_c222_ev": float(np.median(np.abs(out2 - target))) if len(i1) else math.nan,
            "implied_offset_ev": offset}
