"""The controller wrappers: a delayed controller's commands land `latency_frames` after the frame they came from."""

import numpy as np
import pytest

from expoctl.controllers.base import Controller, DelayedController, Settings
from expoctl.sim.closed_loop import FunctionScene, run_closed_loop


class FrameStamp(Controller):
    """Commands an exposure that names the frame it was computed from: 1000 µs + 10 µs × (mean grey of that frame),
    where the scene makes frame t's grey level t."""

    name = "stamp"

    def reset(self, initial):
        self.seen = []

    def update(self, image, applied):
        self.seen.append(applied)
        return Settings(0.0, 1000.0 + 10.0 * float(image.mean()))


class PassThroughSensor:
    def capture(self, luminance, exposure_us, gain_db, rng):  # grey level = the scene's value, whatever the settings
        return np.clip(luminance, 0, 255).astype(np.uint8)


def _drive(latency, n=8):
    scene = FunctionScene(lambda t, e, c: np.full((4, 4, 3), float(t), np.float32), fps=15.0)
    inner = FrameStamp()
    ctrl = inner if latency is None else DelayedController(inner, latency)
    frames = list(run_closed_loop(scene, [PassThroughSensor()], ctrl, Settings(0.0, 500.0), range(n), seed=0))
    return [f.camera(1).settings.exposure_us for f in frames], inner


@pytest.mark.parametrize("latency", [1, 2, 3])
def test_settings_from_frame_t_expose_frame_t_plus_latency(latency):
    exposures, inner = _drive(latency)
    # frames before the first command lands keep the initial 500 µs; then frame t carries frame (t − latency)'s stamp
    assert exposures == [500.0] * latency + [1000.0 + 10.0 * (t - latency) for t in range(latency, 8)]
    # the inner controller saw every frame with the settings it was really exposed with
    assert [s.exposure_us for s in inner.seen] == exposures[:len(inner.seen)]


def test_latency_one_is_the_plain_controller():
    assert _drive(1)[0] == _drive(None)[0]


def test_reset_refills_the_pipeline_and_bad_latency_is_refused():
    ctrl = DelayedController(FrameStamp(), 2)
    ctrl.reset(Settings(0.0, 500.0))
    assert ctrl.update(np.zeros((2, 2, 3), np.uint8), Settings(0.0, 500.0)).exposure_us == 500.0
    ctrl.reset(Settings(3.0, 700.0))  # a new sequence: what was in flight is dropped
    assert ctrl.update(np.zeros((2, 2, 3), np.uint8), Settings(3.0, 700.0)) == Settings(3.0, 700.0)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError):
            DelayedController(FrameStamp(), bad)


@pytest.mark.parametrize("value, problem", [(1, None), (3, None), (0, "must be an integer >= 1, got 0"),
                                            (True, "must be an integer >= 1, got True"),
                                            (1.5, "must be an integer >= 1, got 1.5")])
def test_latency_frames_has_one_definition(value, problem):
    """controllers.learned.latency_frames and labels.latency_frames (which follows it) are read by one function."""
    from expoctl.config_reader import Section
    from expoctl.controllers.base import read_latency_frames
    from expoctl.errors import ConfigError
    from expoctl.labels.targets import LabelConfig

    for key in ("controllers.learned", "labels"):
        r = Section({"latency_frames": value}, key)
        got = read_latency_frames(r)
        if problem is None:
            assert got == value
            r.done()
        else:
            with pytest.raises(ConfigError) as exc:
                r.done()
            assert exc.value.problems == [(f"{key}.latency_frames", problem)]
    assert read_latency_frames(Section({}, "labels")) == 1 == LabelConfig.from_dict({}).latency_frames
