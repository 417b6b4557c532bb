"""AG+AE model: metering in the linear domain, exposure-first split, step limit, latency, step response."""

import math

import numpy as np
import pytest

from expoctl.camera.ranges import exposure_value_ev
from expoctl.controllers.agae import AgAeController
from expoctl.controllers.base import Settings
from expoctl.camera.response import linear_to_8bit
from expoctl.errors import ConfigError

P_REF = 1000.0  # µs·(linear gain) at which a scene radiance of 1.0 fills full scale


def _product(s: Settings) -> float:
    return s.exposure_us * 10 ** (s.gain_db / 20)


def _scene(seed=0, shape=(48, 64)):
    """Textured scene with a ±1 EV log-normal spread around radiance 1 (mean linear ≈ 1.06)."""
    rng = np.random.default_rng(seed)
    return np.exp(rng.normal(0.0, 0.5, size=shape))


def _capture(radiance, s: Settings) -> np.ndarray:
    lin = np.clip(radiance * _product(s) / P_REF, 0.0, 1.0)
    return np.repeat(linear_to_8bit(lin)[..., None], 3, axis=2)


def _close(a: Settings, b: Settings) -> bool:
    return a.gain_db == pytest.approx(b.gain_db, abs=1e-9) and a.exposure_us == pytest.approx(b.exposure_us, rel=1e-12)


def _run_closed_loop(ctrl, radiance_per_frame, initial: Settings):
    """Caller semantics: settings returned at t are applied at t+1."""
    ctrl.reset(initial)
    s = initial
    applied = []
    for rad in radiance_per_frame:
        applied.append(s)
        s = ctrl.update(_capture(rad, s), s)
    return applied


def test_metering_uses_the_linear_image():
    """A uniform image of code 118 is ≈18 % linear through sRGB: at 18 % target the AE must not move."""
    c = AgAeController({"internal_latency_frames": 0, "damping": 0.0})
    c.reset(Settings(0.0, 5000.0))
    img = np.full((10, 10, 3), 118, np.uint8)
    out = c.update(img, Settings(0.0, 5000.0))
    lin = ((118 / 255 + 0.055) / 1.055) ** 2.4
    assert out.exposure_us == pytest.approx(5000.0 * 0.18 / lin, rel=1e-6)  # float32 inverse LUT
    assert abs(math.log2(out.exposure_us / 5000.0)) < 0.02  # a gamma-domain meter would be off by ~1.4 EV


def test_response_curve_is_configurable():
    """With a plain 2.2 power law, code 128 is (128/255)^2.2 linear; the AE must meter exactly that."""
    img = np.full((4, 4, 3), 128, np.uint8)
    m_gamma = AgAeController({"response_curve": "gamma", "response_gamma": 2.2}).metered_mean(img)
    m_linear = AgAeController({"response_curve": "linear"}).metered_mean(img)
    assert m_gamma == pytest.approx((128 / 255) ** 2.2, rel=1e-6) and m_linear == pytest.approx(128 / 255, rel=1e-6)


def test_damping_fraction_and_one_extra_frame_of_latency():
    """Frame 0 is metered but only acted upon at the second update (internal latency 1); then (1-damping) of the
    log error is corrected."""
    c = AgAeController({"damping": 0.2, "max_brighten_ev_per_frame": 10.0})
    s0 = Settings(0.0, 1000.0)
    c.reset(s0)
    dark = np.full((8, 8, 3), linear_to_8bit(np.array(0.09))[()], np.uint8)  # ≈ 1 EV under the 18 % target
    assert _close(c.update(dark, s0), s0)  # nothing measured yet is acted on
    m = c.metered_mean(dark)
    out = c.update(dark, s0)
    assert math.log(out.exposure_us / 1000.0) == pytest.approx(0.8 * math.log(0.18 / m), rel=1e-9)


def test_step_limit_caps_each_frame_change():
    c = AgAeController({"internal_latency_frames": 0, "damping": 0.2, "max_brighten_ev_per_frame": 0.5,
                        "max_darken_ev_per_frame": 0.5})
    c.reset(Settings(0.0, 1000.0))
    out = c.update(np.zeros((8, 8, 3), np.uint8), Settings(0.0, 1000.0))
    assert out.exposure_us == pytest.approx(1000.0 * 2**0.5)
    out = c.update(np.full((8, 8, 3), 255, np.uint8), Settings(0.0, 1000.0))
    assert out.exposure_us == pytest.approx(1000.0)  # back down 0.5 EV from the internal command


def test_darkening_and_brightening_limits_are_separate():
    """The real camera brightened by up to 0.51 EV in one frame at the entry but never darkened faster than
    0.178 EV per frame at the exit: a black frame steps up by the first, a white one down by the second."""
    c = AgAeController({"internal_latency_frames": 0, "damping": 0.0})
    c.reset(Settings(0.0, 1000.0))
    up = c.update(np.zeros((8, 8, 3), np.uint8), Settings(0.0, 1000.0))
    assert math.log2(up.exposure_us / 1000.0) == pytest.approx(0.51)
    c.reset(Settings(0.0, 1000.0))
    down = c.update(np.full((8, 8, 3), 255, np.uint8), Settings(0.0, 1000.0))
    assert math.log2(down.exposure_us / 1000.0) == pytest.approx(-0.178)


def test_fitted_loop_shrinks_consecutive_steps_by_the_recorded_ratio():
    """After a darkening of the scene, consecutive exposure increases shrink by `damping` per frame (0.873, the
    recorded entry), whatever the latency, because the AE meters each frame against the settings it was shot with."""
    from expoctl.controllers.ae_trace import entry_stats, ev_trace

    scene = _scene(3) * 0.3
    for latency in (1, 2):
        c = AgAeController({"internal_latency_frames": latency})
        frames = [scene] * 40
        applied = _run_closed_loop(c, frames, Settings(0.0, 400.0))
        ev = ev_trace([s.exposure_us for s in applied], [s.gain_db for s in applied])
        st = entry_stats(ev, min_step_ev=0.01)
        assert st.shrink_ratio == pytest.approx(0.873, abs=0.01)
        assert st.first_step_frame == 1 + latency  # the first change lands latency + 1 frames after frame 0


def test_exposure_first_split_and_clamps():
    c = AgAeController()
    assert _close(c.split(math.log(2000.0)), Settings(0.0, 2000.0))  # gain stays at its lower limit
    s = c.split(math.log(30000.0 * 10 ** (12 / 20)))  # 12 dB beyond the exposure limit
    assert s.exposure_us == pytest.approx(30000.0) and s.gain_db == pytest.approx(12.0)
    s = c.split(math.log(30000.0 * 10 ** (40 / 20)))
    assert _close(s, Settings(30.0, 30000.0))
    assert _close(c.split(math.log(10.0)), Settings(0.0, 19.0))  # the camera's own floor, below the network's 75 µs


def test_gain_first_priority_moves_gain_at_fixed_exposure():
    c = AgAeController({"priority": "gain_first", "gain_first_exposure_us": 5000.0})
    s = c.split(math.log(5000.0 * 10 ** (6 / 20)))
    assert s.exposure_us == pytest.approx(5000.0) and s.gain_db == pytest.approx(6.0)
    s = c.split(math.log(20000.0 * 10 ** (30 / 20)))
    assert s.exposure_us == pytest.approx(20000.0) and s.gain_db == pytest.approx(30.0)
    s = c.split(math.log(1000.0))
    assert s.exposure_us == pytest.approx(1000.0) and s.gain_db == pytest.approx(0.0)


@pytest.mark.parametrize("code", [0, 255])
def test_black_and_saturated_frames_give_finite_clamped_settings(code):
    c = AgAeController()
    s = Settings(15.0, 10000.0)
    c.reset(s)
    img = np.full((16, 16, 3), code, np.uint8)
    for _ in range(200):
        s = c.update(img, s)
        assert np.isfinite([s.gain_db, s.exposure_us]).all()
        assert s == s.clamped()
    assert s == (Settings(30.0, 30000.0) if code == 0 else Settings(0.0, 19.0))  # pinned at the camera's limits


def test_metering_modes_see_only_their_region():
    img = np.zeros((100, 100, 3), np.uint8)
    img[40:60, 40:60] = 255  # bright centre (4 % of the frame)
    spot = AgAeController({"metering_mode": "spot"}).metered_mean(img)
    avg = AgAeController({"metering_mode": "average"}).metered_mean(img)
    roi = AgAeController({"roi": [0.0, 0.0, 0.3, 0.3]}).metered_mean(img)
    assert spot == pytest.approx(1.0) and avg == pytest.approx(0.04) and roi == pytest.approx(1e-4)


# dark scene whose ideal product is 30 ms at +20 dB; 10 EV brighter needs 293 µs at 0 dB: both inside the range
P_DARK = 30000.0 * 10.0


def _settling_frames(ev_step: float, params: dict | None = None) -> tuple[int, list[float]]:
    """Start settled on one scene, step its radiance by `ev_step` EV, count frames until the product stays within
    1/3 EV of its final value. Returns (frames after the step, per-frame EV changes)."""
    scene = _scene()
    lin_mean = np.mean(np.clip(scene * 0.1, 0, 1)) / 0.1  # mean radiance (no clipping at this scale)
    dark = scene * 0.18 * P_REF / (P_DARK * lin_mean)
    first, second = (dark, dark * 2**ev_step) if ev_step > 0 else (dark * 2**-ev_step, dark)
    n_before, n_after = 40, 90
    c = AgAeController(params)
    applied = _run_closed_loop(c, [first] * n_before + [second] * n_after, Settings(0.0, 5000.0))
    # settled = the product is within 1/3 EV (one EV-compensation step) of its final value from then on
    ev = np.array([exposure_value_ev(s.gain_db, s.exposure_us) for s in applied])
    off = np.abs(ev - ev[-1]) > 1 / 3
    last_off = int(np.nonzero(off[n_before:])[0].max())
    return last_off + 1, list(np.diff(ev))


OLD_LOOP = {"damping": 0.2, "max_brighten_ev_per_frame": 0.5, "max_darken_ev_per_frame": 0.5}


def test_old_loop_step_response_10_ev_exit_is_rate_limited():
    """The old loop (still reachable as config): a 10 EV brightening (tunnel exit) meters m≈1 on saturated frames, so
    the 0.5 EV/frame limit sets the pace. Settling needs ≥ 10/0.5 − 5 frames (the last ~2.5 EV are seen unsaturated)
    plus 2 frames of latency; no frame-to-frame change exceeds 0.5 EV."""
    frames, dev = _settling_frames(10.0, OLD_LOOP)
    assert 17 <= frames <= 25, frames
    assert max(abs(d) for d in dev) <= 0.5 + 1e-9
    frames_down, _ = _settling_frames(-10.0, OLD_LOOP)  # tunnel entry: black frames, metering floor, same limit
    assert 17 <= frames_down <= 25, frames_down


def test_fitted_loop_10_ev_exit_takes_the_real_cameras_time():
    """The fitted loop darkens by at most 0.178 EV per frame. While saturated (the first ~7.5 of 10 EV) it runs at
    that limit: ≥ 7.5 / 0.178 = 42 frames; the last ~2.5 EV, seen unsaturated, decay by 0.873 per frame:
    ln(2.5 / (1/3)) / −ln 0.873 ≈ 15 more frames, plus 2 of latency: at most ~60 frames (4 s at 15 Hz)."""
    frames, dev = _settling_frames(10.0)
    assert 42 <= frames <= 60, frames
    assert -min(dev) == pytest.approx(0.178, abs=1e-6)  # the darkening limit is reached, and never exceeded


def test_settles_to_the_target_grey_without_oscillation():
    rad = [_scene()] * 60
    c = AgAeController()
    applied = _run_closed_loop(c, rad, Settings(0.0, 75.0))  # ≈ 1 EV under the target
    last = _capture(rad[-1], applied[-1])
    assert c.metered_mean(last) == pytest.approx(0.18, rel=0.03)
    ev = np.array([exposure_value_ev(s.gain_db, s.exposure_us) for s in applied])
    assert np.all(np.diff(ev) >= -1e-4)  # (1e-4 EV: 8-bit quantisation jitter)  # monotone approach from below: no overshoot through the latency


@pytest.mark.parametrize(
    "params,key",
    [
        ({"damping": 1.0}, "controllers.agae.damping"),
        ({"target_grey_pct": 0}, "controllers.agae.target_grey_pct"),
        ({"metering_mode": "matrix"}, "controllers.agae.metering_mode"),
        ({"roi": [0.5, 0, 0.2, 1]}, "controllers.agae.roi"),
        ({"max_darken_ev_per_frame": "x"}, "controllers.agae.max_darken_ev_per_frame"),
        ({"max_brighten_ev_per_frame": 0.0}, "controllers.agae.max_brighten_ev_per_frame"),
        ({"exposure_lower_us": 5.0}, "controllers.agae.exposure_upper_us"),
        ({"exposure_upper_us": 50000.0}, "controllers.agae.exposure_upper_us"),
        ({"dampnig": 0.2}, "controllers.agae.dampnig"),
        ({"internal_latency_frames": 1.5}, "controllers.agae.internal_latency_frames"),
        ({"response_curve": "log"}, "controllers.agae.response_curve"),
    ],
)
def test_bad_config_names_the_key(params, key):
    with pytest.raises(ConfigError) as e:
        AgAeController(params)
    assert e.value.key == key


def test_meters_a_per_channel_response_channel_by_channel():
    """Each channel encodes linear 18 % through its own curve (gammas, pedestals, white balance differ): an AE that
    inverts the same per-channel response meters exactly the target, one that assumes sRGB does not."""
    from expoctl.camera.response import Response

    keys = {"response_curve": "gamma", "response_gamma_rgb": [2.8, 1.8, 2.4], "response_pedestal_rgb": [-0.1, 0.05, 0.1],
            "white_balance_rgb": [1.0, 1.3, 0.8]}
    resp = Response("gamma", keys["response_gamma_rgb"], keys["response_pedestal_rgb"], keys["white_balance_rgb"])
    img = np.broadcast_to(resp.linear_to_8bit(np.full(3, 0.18)), (8, 8, 3)).copy()
    assert len(set(img[0, 0].tolist())) == 3
    assert AgAeController(keys).metered_mean(img) == pytest.approx(0.18, rel=0.02)  # 8-bit rounding
    assert abs(AgAeController({}).metered_mean(img) / 0.18 - 1) > 0.1  # sRGB reads 0.206


def test_bad_per_channel_response_key_is_named():
    with pytest.raises(ConfigError) as e:
        AgAeController({"white_balance_rgb": [1.0, -1.0, 1.0]})
    assert e.value.key == "controllers.agae.white_balance_rgb"
