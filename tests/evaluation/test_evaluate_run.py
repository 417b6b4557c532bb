"""One evaluation run (expoctl.evaluation.run.drive_window): the closed-loop contract and the per-frame rows."""

from __future__ import annotations

import numpy as np
import pytest
from eval_fixtures import K_DN, LinearSensor, moving_scene

from expoctl.controllers.base import Controller, Settings
from expoctl.evaluation.run import WindowFrames, drive_window, image_stats, variants

VARIANTS = variants(("orb", "viso"))
from expoctl.features.orb import OrbFrontEnd
from expoctl.features.sumlog import SumLogParams
from expoctl.features.viso import VisoFrontEnd


class Scripted(Controller):
    """Returns script[i] on its i-th update, whatever it sees; records what it was shown."""

    name = "scripted"

    def __init__(self, script):
        self.script = list(script)
        self.seen: list[tuple[float, Settings]] = []

    def reset(self, initial):
        self.seen.clear()

    def update(self, image, applied):
        self.seen.append((float(image.mean()), applied))
        return self.script[len(self.seen) - 1]


def _window(n, start=0, sections=None):
    sections = sections or ["static"] * n
    return WindowFrames("seq-a", range(start, start + n), sections, np.linspace(-1, 1, n), ["entry"] * n, None)


def _run(controller, n=8, start=0, warmup=0, sensor=None, **kw):
    scene = moving_scene(lambda f: 1000.0)
    K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])
    return drive_window(scene, sensor or LinearSensor(noise_dn=0.0), controller, _window(n, start), seed=3,
                        frontends={"orb": OrbFrontEnd({"working_size": None, "count_nfeatures": 500,
                                                       "match_nfeatures": 500}), "viso": VisoFrontEnd()},
                        sumlog={"orb": SumLogParams(rescale="minmax"), "viso": SumLogParams(rescale="minmax")},
                        initial=Settings(0.0, 5000.0), warmup_frames=warmup, K=K, vo_min_inliers=5, **kw)


def test_settings_from_frame_t_take_effect_at_t_plus_1():
    script = [Settings(float(g), e) for g, e in zip(range(1, 9), [4000, 3000, 2500, 2000, 1500, 1200, 1000, 900])]
    ctrl = Scripted(script)
    rows, summary, _ = _run(ctrl, n=8)
    assert [r["frame"] for r in rows] == list(range(8))
    # frame 0 with the initial settings; frame k with what the controller returned after seeing frame k-1
    assert (rows[0]["gain_db"], rows[0]["exposure_us"]) == (0.0, 5000.0)
    for k in range(1, 8):
        assert (rows[k]["gain_db"], rows[k]["exposure_us"]) == (script[k - 1].gain_db, script[k - 1].exposure_us)
    # the controller saw frame t captured with frame t's settings (never its own newest command)
    assert [s for _, s in ctrl.seen[:8]] == [Settings(r["gain_db"], r["exposure_us"]) for r in rows]
    # and the image really was taken with them: noise-free linear sensor, texture mean ≈ 1 → DN ≈ L·t·K·10^(g/20)
    for r in rows:
        expected = 1000.0 * r["exposure_us"] * 1e-6 * K_DN * 10 ** (r["gain_db"] / 20)
        assert r["mean_grey"] == pytest.approx(min(expected, 255.0), rel=0.08)
    assert summary["n_frames"] == 8


def test_warmup_frames_run_the_controller_but_are_not_recorded():
    script = [Settings(0.0, 1000.0 + 100 * i) for i in range(20)]
    ctrl = Scripted(script)
    rows, _, _ = _run(ctrl, n=5, start=4, warmup=3)
    # 3 warm-up updates happened before the first recorded frame, so frame 0 carries script[2]
    assert rows[0]["exposure_us"] == script[2].exposure_us and rows[0]["traj_frame"] == 4
    assert [r["exposure_us"] for r in rows] == [s.exposure_us for s in script[2:7]]


def test_rows_carry_nfm_for_every_variant_and_vo():
    rows, summary, thumbs = _run(Scripted([Settings(0.0, 5000.0)] * 10), n=6, sensor=LinearSensor(noise_dn=1.0),
                                 thumb_width=40, thumb_every=2, thumb_span_s=10.0)
    for v in VARIANTS:
        assert np.isnan(rows[0][f"nfm_{v}"])  # no predecessor in the window
        for r in rows[1:]:
            assert 0 < r[f"nfm_{v}"] <= r[f"nmatch_{v}"], (v, r)
            assert r[f"nfeat_{v}"] > 0
    assert all(r["vo_n_inliers"] >= 5 for r in rows[1:])
    assert summary["vo_success"] and summary["vo_failed_at"] == -1
    assert list(thumbs["frame"]) == [0, 2, 4] and thumbs["image"].shape == (3, 30, 40, 3)


def test_black_frames_fail_vo_and_give_zero_nfm():
    # 75 µs at 0 dB on 1000 cd/m²: ~2 DN — nothing to detect
    rows, summary, _ = _run(Scripted([Settings(0.0, 75.0)] * 10), n=5)
    assert all(r["nfm_orb"] == 0 for r in rows[1:])
    assert not summary["vo_success"] and summary["vo_failed_at"] == 1


def test_image_stats_exact():
    grey = np.array([[0, 5, 6, 250], [255, 100, 100, 100]], np.uint8)
    s = image_stats(grey)
    assert s["saturated_frac"] == 2 / 8 and s["dark_frac"] == 2 / 8 and s["mean_grey"] == pytest.approx(816 / 8)
