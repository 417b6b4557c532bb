import numpy as np
import pytest

from expoctl.controllers.base import Controller, Settings
from expoctl.sim.closed_loop import FunctionScene, run_closed_loop
from expoctl.sim.protocol import PerturbationConfig, perturb


class EncodingSensor:
    """Writes what it was asked to capture into the pixels: frame (from the scene), gain, exposure/100, noise."""

    def capture(self, luminance, exposure_us, gain_db, rng):
        img = np.zeros((2, 2, 3), np.uint8)
        img[..., 0] = int(luminance[0, 0, 0])
        img[..., 1] = int(round(gain_db))
        img[..., 2] = min(255, int(round(exposure_us / 100.0)))
        img[1, 1, :] = rng.integers(0, 256, size=3)
        return img


class ScriptedController(Controller):
    """Returns a scripted settings sequence, one per update call, and records what it saw."""

    name = "scripted"

    def __init__(self, script):
        self.script = list(script)
        self.seen = []

    def reset(self, initial):
        self.seen = []
        self.initial = initial

    def update(self, image, applied):
        self.seen.append((int(image[0, 0, 0]), int(image[0, 0, 1]), int(image[0, 0, 2]), applied))
        return self.script[len(self.seen) - 1]


def frame_scene(fps=15.0):
    # luminance encodes the frame index, so the sensor can write it into the image
    return FunctionScene(lambda t, exposure_us, camera: np.full((2, 2, 3), float(t), np.float32), fps=fps)


SCRIPT = [Settings(float(g), 1000.0 + 100.0 * g) for g in range(1, 30)]


def test_settings_from_frame_t_apply_at_t_plus_1():
    ctrl = ScriptedController(SCRIPT)
    initial = Settings(0.0, 500.0)
    out = list(run_closed_loop(frame_scene(), [EncodingSensor()], ctrl, initial, range(0, 10), seed=1))
    assert [f.frame_index for f in out] == list(range(10))
    assert out[0].camera(1).settings == initial
    for t in range(1, 10):
        # frame t was captured with what the controller returned after seeing frame t-1 (not earlier, not later)
        assert out[t].camera(1).settings == SCRIPT[t - 1]
        assert out[t].camera(1).image[0, 0, 1] == round(SCRIPT[t - 1].gain_db)
    # the controller saw frame t with the settings frame t was captured with
    for t, (frame, gain, exp100, applied) in enumerate(ctrl.seen):
        assert frame == t
        assert applied == out[t].camera(1).settings
        assert (gain, exp100) == (round(applied.gain_db), round(applied.exposure_us / 100))
    assert [f.timestamp_ns for f in out[:3]] == [0, 66666667, 133333333]


def test_camera2_is_the_perturbation_of_camera1_same_frame():
    ctrl = ScriptedController(SCRIPT)
    cfg = PerturbationConfig()
    out = list(
        run_closed_loop(frame_scene(), [EncodingSensor(), EncodingSensor()], ctrl, Settings(3.0, 900.0), range(5, 13),
                        seed=9, perturbation=cfg, warmup_frames=3)
    )
    assert [f.frame_index for f in out] == list(range(5, 13))
    for f in out:
        s1, s2 = f.camera(1).settings, f.camera(2).settings
        assert s2 == perturb(s1, f.frame_index, 9, cfg)
        assert f.camera(2).image[0, 0, 0] == f.frame_index
    # warm-up ran the controller on frames 2, 3, 4 (camera 1 only) before the first recorded frame
    assert [s[0] for s in ctrl.seen[:4]] == [2, 3, 4, 5]
    assert out[0].camera(1).settings == SCRIPT[2]


def test_warmup_clipped_at_the_first_frame():
    ctrl = ScriptedController(SCRIPT)
    out = list(run_closed_loop(frame_scene(), [EncodingSensor()], ctrl, Settings(0, 500), range(1, 3), seed=0, warmup_frames=5))
    assert [s[0] for s in ctrl.seen] == [0, 1, 2]
    assert out[0].camera(1).settings == SCRIPT[0]


def test_sensor_noise_depends_only_on_seed_camera_frame():
    def noise(frames, warmup, seed):
        out = run_closed_loop(frame_scene(), [EncodingSensor(), EncodingSensor()], ScriptedController(SCRIPT),
                              Settings(0, 500), frames, seed=seed, perturbation=PerturbationConfig(), warmup_frames=warmup)
        return {(f.frame_index, c.camera): c.image[1, 1].tolist() for f in out for c in f.cameras}

    a = noise(range(4, 8), 0, seed=3)
    b = noise(range(2, 8), 2, seed=3)
    assert all(a[k] == b[k] for k in a)
    assert a[(5, 1)] != a[(5, 2)]
    assert noise(range(4, 8), 0, seed=4) != a


def test_two_controllers_side_by_side():
    c1 = ScriptedController(SCRIPT)
    c2 = ScriptedController([Settings(20.0, 2000.0 + t) for t in range(30)])
    out = list(run_closed_loop(frame_scene(), [EncodingSensor(), EncodingSensor()], c1, Settings(1, 500), range(4), seed=0,
                               camera2_controller=c2, camera2_initial=Settings(2, 600)))
    assert out[0].camera(2).settings == Settings(2, 600)
    assert [f.camera(2).settings.exposure_us for f in out[1:]] == [2000.0, 2001.0, 2002.0]
    assert [s[0] for s in c2.seen] == [0, 1, 2, 3]


def test_out_of_range_commands_are_clamped_and_nan_is_refused():
    ctrl = ScriptedController([Settings(99.0, 1e9), Settings(-5.0, 1.0), Settings(float("nan"), 100.0)])
    it = run_closed_loop(frame_scene(), [EncodingSensor()], ctrl, Settings(0, 500), range(10), seed=0)
    frames = [next(it), next(it), next(it)]
    assert frames[1].camera(1).settings == Settings(30.0, 30000.0)
    assert frames[2].camera(1).settings == Settings(0.0, 19.0)  # the camera's own floor
    with pytest.raises(ValueError, match="non-finite"):
        next(it)


def test_bad_camera_options():
    with pytest.raises(ValueError):
        list(run_closed_loop(frame_scene(), [EncodingSensor(), EncodingSensor()], ScriptedController(SCRIPT),
                             Settings(0, 500), range(3), seed=0))
    with pytest.raises(ValueError):
        list(run_closed_loop(frame_scene(), [EncodingSensor()], ScriptedController(SCRIPT), Settings(0, 500), range(3),
                             seed=0, perturbation=PerturbationConfig()))


def test_route_scene_coarse_render_is_the_same_scene_at_a_fraction_of_the_size():
    # the oracle's candidate_render "match": the camera's render at 1/k of the width and height, same field of view
    # and exposure; the full-size renders are untouched by it
    from dataclasses import replace

    from expoctl.sim.closed_loop import RenderConfig, RigConfig, RouteScene
    from expoctl.world import Renderer, load_city

    city = load_city("train")
    traj = city.traversal(0, 12, fps=15.0, seed=0)
    render = RenderConfig(width=64, height=48)
    scene = RouteScene(city, traj, RigConfig(), render)
    full = scene.luminance(10, 4000.0, 1)
    coarse = scene.luminance_coarse(10, 4000.0, 1, 2)
    alone = Renderer(city, replace(render, width=32, height=24))
    np.testing.assert_array_equal(coarse, alone.render_exposure(traj, 10, 4000.0))
    assert coarse.shape == (24, 32, 3) and full.shape == (48, 64, 3)
    np.testing.assert_array_equal(scene.luminance(10, 4000.0, 1), full)
    # the same scene: one ray per coarse pixel against the mean of the four full-size rays it covers. Texture and
    # edges make single blocks differ, but the typical block agrees within a few % (measured 2.4-3.7 % on frames 2
    # and 10 at 64×48 and 160×120; a coarse render of another pose or exposure is off by far more)
    blocks = full.reshape(24, 2, 32, 2, 3).mean(axis=(1, 3))
    assert float(np.median(np.abs(np.log(coarse + 1e-3) - np.log(blocks + 1e-3)))) < 0.06
    other = scene.luminance_coarse(2, 4000.0, 1, 2)
    assert float(np.median(np.abs(np.log(other + 1e-3) - np.log(blocks + 1e-3)))) > 0.06
    with pytest.raises(ValueError, match="coarse factor 5 does not divide the 64x48 render"):
        scene.luminance_coarse(10, 4000.0, 1, 5)
