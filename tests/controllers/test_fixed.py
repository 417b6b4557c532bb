"""Fixed controller: manual lock, AG+AE warm-up lock, first-frame grid search."""

import numpy as np
import pytest

from expoctl.controllers.agae import AgAeController
from expoctl.controllers.base import Settings
from expoctl.controllers.fixed import FixedController, grid_search_first_frame, orb_keypoint_count
from expoctl.errors import ConfigError


def test_manual_mode_never_moves():
    c = FixedController({"mode": "manual", "gain_db": 6.0, "exposure_us": 8000.0})
    c.reset(Settings(0.0, 100.0))
    for code in (0, 255, 128):
        assert c.update(np.full((8, 8, 3), code, np.uint8), Settings(0.0, 100.0)) == Settings(6.0, 8000.0)


def test_agae_warmup_follows_agae_then_locks():
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 120, (16, 16, 3)).astype(np.uint8) for _ in range(12)]
    fixed = FixedController({"warmup_frames": 5})
    ref = AgAeController()
    s0 = Settings(0.0, 1000.0)
    fixed.reset(s0)
    ref.reset(s0)
    s_f = s_r = s0
    outs = []
    for i, img in enumerate(frames):
        s_f = fixed.update(img, s_f)
        if i < 5:
            s_r = ref.update(img, s_r)
            assert s_f == s_r
        outs.append(s_f)
    assert fixed.locked == outs[4]
    assert all(o == outs[4] for o in outs[4:])  # locked whatever the images do afterwards
    assert outs[4] != s0  # the warm-up moved (dark frames → longer exposure)
    assert fixed.update(np.full((16, 16, 3), 255, np.uint8), s_f) == outs[4]


def test_grid_search_picks_the_best_and_breaks_ties_towards_low_gain_and_short_exposure():
    def render(s):
        return s  # the score below reads the settings directly

    def score(s):
        return -abs(s.exposure_us - 4000.0) if s.gain_db < 10 else -abs(s.exposure_us - 4000.0)

    best = grid_search_first_frame(render, [0.0, 12.0], [1000.0, 4000.0, 9000.0], score)
    assert best == Settings(0.0, 4000.0)
    assert grid_search_first_frame(render, [6.0, 0.0], [3000.0, 5000.0], lambda s: 1.0) == Settings(0.0, 3000.0)


def test_orb_score_prefers_texture_over_flat():
    rng = np.random.default_rng(0)
    tex = np.repeat(rng.integers(0, 256, (120, 160, 1)), 3, axis=2).astype(np.uint8)
    assert orb_keypoint_count(tex) > 50 and orb_keypoint_count(np.zeros_like(tex)) == 0


@pytest.mark.parametrize(
    "params,key",
    [({"mode": "auto"}, "controllers.fixed.mode"), ({"exposure_us": 50000.0}, "controllers.fixed.exposure_us"),
     ({"warmup_frames": 0}, "controllers.fixed.warmup_frames"), ({"agae": {"damping": 2.0}}, "controllers.fixed.agae.damping")],
)
def test_bad_config(params, key):
    with pytest.raises(ConfigError) as e:
        FixedController(params)
    assert e.value.key == key
