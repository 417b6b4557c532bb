"""Camera-independent parts: pixel conversion, limits, actuation-delay bookkeeping, and the live rig's pairing on
top of the library's loop (with an in-memory camera whose behaviour each test scripts)."""

from __future__ import annotations

import numpy as np
import pytest

from expoctl.hardware.base import (
    Camera,
    CameraError,
    CameraInfo,
    Frame,
    Limits,
    Range,
    UserLimits,
    effective_limits,
    to_rgb8,
)
from expoctl.hardware.live import ActuationDelay, LiveRig
from expoctl.controllers.base import Controller, Settings
from expoctl.sim.closed_loop import drive_rig
from expoctl.sim.protocol import PerturbationConfig, perturb


def _mosaic(rgb: np.ndarray, tile: str) -> np.ndarray:
    """Sample an RGB image through a Bayer colour filter with 2×2 tile `tile` (e.g. "RGGB": R at (0, 0))."""
    chan = {"R": 0, "G": 1, "B": 2}
    out = np.zeros(rgb.shape[:2], np.uint8)
    for k, (dy, dx) in enumerate(((0, 0), (0, 1), (1, 0), (1, 1))):
        out[dy::2, dx::2] = rgb[dy::2, dx::2, chan[tile[k]]]
    return out


@pytest.mark.parametrize("fmt,tile", [("BayerRG8", "RGGB"), ("BayerGR8", "GRBG"), ("BayerGB8", "GBRG"),
                                      ("BayerBG8", "BGGR")])
def test_bayer_formats_demosaic_to_the_right_colours(fmt, tile):
    rgb = np.zeros((8, 10, 3), np.uint8)
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 200, 100, 30  # a flat orange scene
    out = to_rgb8(_mosaic(rgb, tile).tobytes(), 10, 8, fmt)
    assert out.shape == (8, 10, 3) and out.dtype == np.uint8
    np.testing.assert_allclose(out[2:-2, 2:-2].reshape(-1, 3).mean(axis=0), [200, 100, 30], atol=2)


def test_mono_and_rgb_formats_and_bad_buffers():
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    out = to_rgb8(grey.tobytes(), 4, 3, "Mono8")
    assert out.shape == (3, 4, 3) and (out[..., 0] == grey).all() and (out[..., 2] == grey).all()
    bgr = np.zeros((3, 4, 3), np.uint8)
    bgr[..., 0] = 7
    assert (to_rgb8(bgr.tobytes(), 4, 3, "BGR8")[..., 2] == 7).all()
    with pytest.raises(ValueError, match="Mono16 is not supported"):
        to_rgb8(b"\0" * 24, 4, 3, "Mono16")
    with pytest.raises(ValueError, match="too short"):
        to_rgb8(b"\0" * 5, 4, 3, "Mono8")


CAM = Limits(Range(0.0, 48.0), Range(10.0, 1e7))


def test_effective_limits_intersect_camera_library_and_user():
    lim = effective_limits("cam0", CAM, UserLimits(gain_max_db=12.0, exposure_min_us=100.0))
    assert lim == Limits(Range(0.0, 12.0), Range(100.0, 30000.0))
    assert effective_limits("cam0", Limits(Range(0.0, 10.0), Range(20.0, 20000.0))) == \
        Limits(Range(0.0, 10.0), Range(75.0, 20000.0))


def test_every_out_of_range_limit_named_in_one_message():
    with pytest.raises(CameraError) as exc:
        effective_limits("cam0", CAM, UserLimits(gain_max_db=60.0, exposure_max_us=5.0, gain_min_db=40.0))
    msg = str(exc.value)
    assert msg.startswith("camera cam0: ")
    assert "--gain-max-db 60 dB is outside camera cam0's range 0–48 dB" in msg
    assert "--exposure-max-us 5 µs is outside camera cam0's range 10–1e+07 µs" in msg
    assert "--gain-min-db 40 dB is outside the range expoctl models and records (0–30 dB)" in msg


def test_actuation_delay_counts_frames_until_a_change_shows():
    d = ActuationDelay()
    a, b = Settings(0.0, 1000.0), Settings(0.0, 2000.0)
    d.commanded(10, b, previous=a)  # computed from frame 10
    assert d.observed(11, a) is None and d.observed(12, a) is None
    assert d.observed(13, Settings(0.0, 2001.0)) == 3  # within the device's rounding
    d.commanded(13, b, previous=b)  # no change: nothing to see
    assert d.observed(14, b) is None
    d.commanded(14, a, previous=b)
    d.commanded(15, Settings(6.0, 1000.0), previous=a)  # overtakes the command from frame 14
    assert d.observed(16, Settings(6.0, 1000.0)) == 1
    assert d.delays == [3, 1]


class Clock:
    """The rig's shared time: advances one 40 ms frame period per trigger of camera 1."""

    def __init__(self):
        self.ns = 0


class ScriptedCamera(Camera):
    """In memory: applies a command at once (rounded like a device), reports it by read-back, numbers its frames,
    stamps them with the shared clock (+ its own `t0_ns` offset) and sends frame n `late(n)` ms late."""

    def __init__(self, name: str, clock: Clock, t0_ns: int = 0, late=lambda n: 0.0, leader: bool = False):
        self.clock, self.leader = clock, leader
        self.info = CameraInfo(camera_id=name, backend="memory", resolution=(4, 2))
        self.limits = Limits(Range(0.0, 30.0), Range(75.0, 30000.0))
        self.register = Settings(0.0, 1000.0)
        self.frame_no, self.t0_ns, self.late = 0, t0_ns, late
        self.triggers, self.queued = 0, 0

    def read_settings(self):
        return self.register

    def apply(self, settings):
        self.register = Settings(round(settings.gain_db / 6.0) * 6.0, float(round(settings.exposure_us)))
        return self.register

    def start(self, triggered):
        self.triggered = triggered

    def trigger(self):
        self.triggers += 1
        if self.leader:
            self.clock.ns += 40_000_000

    def discard_queued(self):
        n, self.queued = self.queued, 0
        return n

    def grab(self, timeout_s, newest=False):
        self.frame_no += 1
        img = np.full((2, 4, 3), int(self.register.exposure_us) % 256, np.uint8)
        ts = self.clock.ns + self.t0_ns + int(self.late(self.frame_no) * 1e6)
        return Frame(img, self.register, "readback", ts, ts, self.frame_no), 0

    def stop(self):
        pass

    def close(self):
        pass


class Ramp(Controller):
    name = "ramp"

    def reset(self, initial):
        self.n = 0

    def update(self, image, applied):
        self.n += 1
        return Settings(applied.gain_db, applied.exposure_us + 100.3)


def test_live_rig_runs_the_library_loop_with_the_shared_perturbation():
    clock = Clock()
    cams = [ScriptedCamera("A", clock, leader=True), ScriptedCamera("B", clock, t0_ns=1_000_000)]
    rig = LiveRig(cams, [c.limits for c in cams], triggered=True, pair_tolerance_ms=10.0)
    cfg = PerturbationConfig()
    frames = list(drive_rig(rig, 2, Ramp(), Settings(0.0, 1000.0), range(3, 9), seed=5, perturbation=cfg,
                            warmup_frames=3, limit=rig.limit))
    assert [f.frame_index for f in frames] == list(range(3, 9))
    for f in frames:
        s1, s2 = f.camera(1).settings, f.camera(2).settings
        want = perturb(s1, f.frame_index, 5, cfg)  # camera 1's command for t, perturbed for frame t
        assert s2.exposure_us == pytest.approx(round(want.exposure_us), abs=1.0)
        assert s2.gain_db == round(want.gain_db / 6.0) * 6.0
        assert f.camera(2).timestamp_ns - f.camera(1).timestamp_ns == 1_000_000
    assert cams[0].triggers == 9 and cams[1].triggers == 6  # warm-up frames trigger camera 1 only
    assert rig.stats.mispaired == 0 and rig.stats.camera_frames_missed == [0, 0]
    assert rig.delay[0].delays and set(rig.delay[0].delays) == {1}  # read-back: the register shows it at once


def test_live_rig_retriggers_a_mispaired_frame_then_gives_up_naming_both_cameras():
    clock = Clock()
    cams = [ScriptedCamera("A", clock, leader=True), ScriptedCamera("B", clock, late=lambda n: 25.0 if n == 2 else 0.0)]
    rig = LiveRig(cams, [c.limits for c in cams], triggered=True, pair_tolerance_ms=10.0)
    loop = drive_rig(rig, 2, Ramp(), Settings(0.0, 1000.0), range(0, 4), seed=0, perturbation=PerturbationConfig(),
                     limit=rig.limit)
    frames = list(loop)
    assert len(frames) == 4 and rig.stats.mispaired == 1
    assert max(rig.stats.pair_offsets_ms) <= 10.0
    assert rig.stats.camera_frames_missed == [0, 0]  # the discarded pair was received: not a transport loss
    always_late = [ScriptedCamera("A", clock, leader=True), ScriptedCamera("B", clock, late=lambda n: 30.0)]
    rig = LiveRig(always_late, [c.limits for c in always_late], triggered=True, pair_tolerance_ms=10.0)
    with pytest.raises(CameraError, match=r"cameras A and B: the two frames of one trigger arrived -30\.0 ms apart"):
        list(drive_rig(rig, 2, Ramp(), Settings(0.0, 1000.0), range(0, 4), seed=0,
                       perturbation=PerturbationConfig(), limit=rig.limit))


def test_controller_config_for_a_camera(tmp_path):
    from expoctl.hardware.session import camera_controller_names, controller_config, make_camera_controller
    from expoctl.controllers.agae import AgAeConfig
    from expoctl.errors import InputError

    # every registered controller but the oracle (it needs the simulator's scene) can drive a camera
    assert camera_controller_names() == ("agae", "shin", "shim", "mean_intensity", "fixed", "learned")
    lim = Limits(Range(0.0, 12.0), Range(75.0, 20000.0))
    agae = controller_config("agae", lim)
    assert agae == AgAeConfig(exposure_lower_us=75.0, exposure_upper_us=20000.0, gain_lower_db=0.0, gain_upper_db=12.0)
    assert controller_config("fixed", lim).agae == agae  # its warm-up AG+AE gets the camera's range too
    for name in ("agae", "fixed", "mean_intensity"):  # the library's controllers accept what is built for them
        ctrl = make_camera_controller(name, controller_config(name, lim))
        ctrl.reset(Settings(0.0, 1000.0))
        for _ in range(3):  # AG+AE meters the frame before the newest one: its first command holds
            nxt = ctrl.update(np.zeros((8, 8, 3), np.uint8), Settings(0.0, 1000.0))  # black: brighten
        assert nxt.exposure_us > 1000.0 and nxt.gain_db <= 12.0 and nxt.exposure_us <= 20000.0
    with pytest.raises(InputError, match="--controller 'oracle': unknown or not for a real camera"):
        controller_config("oracle", lim)
    with pytest.raises(InputError, match="controllers.shim.exposure_upper_us"):  # Shim's own 75 µs floor
        controller_config("shim", Limits(Range(0.0, 12.0), Range(20.0, 20000.0)))
    with pytest.raises(InputError, match="--model PATH is needed with --controller learned"):
        controller_config("learned", lim)
    with pytest.raises(InputError, match="--model is only for --controller learned, not agae"):
        controller_config("agae", lim, model="x.pt")
    with pytest.raises(InputError, match="model checkpoint not found"):
        controller_config("learned", lim, model=str(tmp_path / "missing.pt"))
    (tmp_path / "m.pt").write_bytes(b"")
    assert controller_config("learned", lim, model=str(tmp_path / "m.pt")).backend == "torch"  # no .onnx beside it
    (tmp_path / "m.onnx").write_bytes(b"")
    learned = controller_config("learned", lim, model=str(tmp_path / "m.pt"))
    assert (learned.checkpoint, learned.backend, learned.num_threads) == (str(tmp_path / "m.pt"), "onnx", 1)


def test_background_writer_keeps_order_and_reports_a_write_error(tmp_path):
    from expoctl.hardware.session import BackgroundWriter
    from expoctl.raw.format import SequenceWriter

    img = np.zeros((4, 6, 3), np.uint8)
    w = BackgroundWriter(SequenceWriter(tmp_path / "seq", {"source": "rig"}), max_queued=2)
    for fid in range(5):
        w.add_frame(fid, 1, 1000 + fid, 0.0, 1000.0, img + fid)
    path = w.close()
    lines = (path / "frames.csv").read_text().splitlines()
    assert [l.split(",")[0] for l in lines[1:]] == ["0", "1", "2", "3", "4"]

    class Failing:
        meta: dict = {}

        def __init__(self):
            self.aborted = False

        def add_frame(self, *args):
            raise OSError(28, "No space left on device")

        def abort(self):
            self.aborted = True

    inner = Failing()
    w = BackgroundWriter(inner)
    w.add_frame(0, 1, 0, 0.0, 1000.0, img)
    with pytest.raises(OSError, match="No space left"):
        w.close()
    assert inner.aborted
