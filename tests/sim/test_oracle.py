"""The oracle: candidate ladder, config checks, frame counting, and that it scores the real next frame."""

from __future__ import annotations

import numpy as np
import pytest
from eval_fixtures import LinearSensor, moving_scene

from expoctl.controllers.base import Settings
from expoctl.sim.oracle import CachedScene, OracleController, OracleParams
from expoctl.controllers.registry import make_controller
from expoctl.errors import ConfigError
from expoctl.features.pipeline import rgb_to_grey
from expoctl.sim.closed_loop import run_closed_loop


def test_default_ladder_is_exposure_first_at_one_ev_steps():
    c = OracleParams().candidates()
    assert len(c) == 14
    assert [s.gain_db for s in c[:9]] == [0.0] * 9
    assert c[0].exposure_us == 30000.0 and c[8].exposure_us == pytest.approx(30000.0 / 256, abs=0.1)
    assert all(c[i].exposure_us / c[i + 1].exposure_us == pytest.approx(2.0, rel=1e-3) for i in range(8))
    assert [(s.gain_db, s.exposure_us) for s in c[9:]] == [(g, 30000.0) for g in (6.0, 12.0, 18.0, 24.0, 30.0)]


@pytest.mark.parametrize("bad", [{"exposures_us": [10.0]}, {"gains_db": [40.0]}, {"match_width": 8},
                                 {"exposures_us": []}, {"colour": 1}])
def test_bad_config_names_the_key(bad):
    with pytest.raises(ConfigError, match="controllers.oracle"):
        OracleParams.from_dict(bad)


def test_registry_refuses_an_oracle_without_the_simulator():
    from expoctl.controllers import registry
    from expoctl.sim.oracle import register_oracle

    saved = dict(registry.CONTROLLERS)
    try:
        register_oracle()
        with pytest.raises(ConfigError, match="simulator"):
            make_controller("oracle", {})
    finally:
        registry.CONTROLLERS.clear()
        registry.CONTROLLERS.update(saved)


def _loop(level, frames, warmup, noise_dn=2.0, seed=5):
    scene = CachedScene(moving_scene(level))
    sensor = LinearSensor(noise_dn=noise_dn)
    first = max(0, frames.start - warmup)
    oracle = OracleController(scene, sensor, seed, n_frames=100, first_frame=first,
                              params=OracleParams(match_width=160, match_nfeatures=500, objective="match"))
    out = list(run_closed_loop(scene, [sensor], oracle, Settings(0.0, 5000.0), frames, seed, warmup_frames=warmup))
    return out, oracle, scene


def test_oracle_scores_exactly_the_frame_the_camera_then_delivers():
    # a "tunnel exit": 20× brighter from frame 6 on; warm-up starts the loop at frame 2, recording at 4
    frames, oracle, scene = _loop(lambda f: 1000.0 if f < 6 else 20000.0, range(4, 10), warmup=2)
    images = {f.frame_index: f.camera(1).image for f in frames}
    by_frame = {t1: (s, n) for t1, s, n, _ in oracle.choices}
    assert min(by_frame) == 3  # counted from first_frame = 2: its first decision is for frame 3
    fe = oracle._frontend((120, 160))
    for t1 in range(5, 10):
        chosen, n_inl = by_frame[t1]
        f = frames[t1 - 4].camera(1)
        assert f.settings == chosen  # the loop applied the choice at t+1
        # the oracle's inlier count is that of the real pair (t, t+1): same render, same noise
        real = fe.match(fe.extract(rgb_to_grey(images[t1 - 1])), fe.extract(rgb_to_grey(images[t1])), t1)[1]
        assert real == n_inl
    # through the step it never lets the image clip: the bright frames are exposed ~17× shorter
    assert by_frame[6][0].exposure_us <= 30000.0 / 64 and frames[2].camera(1).image.mean() < 200
    assert all(f.camera(1).image.mean() > 40 for f in frames)
    # every candidate exposure rendered once per frame; the loop's own render of the chosen one came from the cache
    n_exposures = len(OracleParams().exposures_us)
    assert scene.n_renders == 1 + n_exposures * (len(oracle.choices))
    assert len(oracle.timings_ms) == len(oracle.choices)


def test_ties_go_to_more_features_then_lower_gain():
    # a black scene: every candidate has 0 inliers and 0 features → the lowest gain, first in ladder order
    frames, oracle, _ = _loop(lambda f: 0.0, range(0, 3), warmup=0, noise_dn=0.0)
    assert all(s == Settings(0.0, 30000.0) for _, s, _, _ in oracle.choices)


def test_no_next_frame_keeps_the_settings():
    scene = moving_scene(lambda f: 1000.0)
    oracle = OracleController(scene, LinearSensor(), 0, n_frames=3, first_frame=2)
    oracle.reset(Settings(3.0, 1234.0))
    img = np.full((120, 160, 3), 100, np.uint8)
    assert oracle.update(img, Settings(3.0, 1234.0)) == Settings(3.0, 1234.0)


def test_hybrid_settings_average_in_the_scaled_ranges():
    from expoctl.sim.oracle import hybrid_settings

    s = hybrid_settings(Settings(0.0, 75.0), Settings(30.0, 30000.0), 0.5)
    assert s.gain_db == pytest.approx(15.0) and s.exposure_us == pytest.approx(75.0 + 0.5 * 29925.0)
    assert hybrid_settings(Settings(6.0, 100.0), Settings(0.0, 9000.0), 1.0) == Settings(6.0, 100.0)
    with pytest.raises(ConfigError, match="controllers.oracle.objective"):
        OracleParams.from_dict({"objective": "best"})


def test_hybrid_objective_commands_between_the_match_and_feature_best():
    scene = CachedScene(moving_scene(lambda f: 1000.0 if f < 6 else 20000.0))
    sensor = LinearSensor(noise_dn=2.0)
    oracle = OracleController(scene, sensor, 5, n_frames=100, first_frame=0,
                              params=OracleParams(match_width=160, match_nfeatures=500, objective="hybrid"))
    frames = list(run_closed_loop(scene, [sensor], oracle, Settings(0.0, 5000.0), range(0, 9), 5))
    exps = OracleParams().exposures_us
    for t1, s, _, _ in oracle.choices:
        assert min(exps) <= s.exposure_us <= max(exps) and s.gain_db == 0.0
    assert len(frames) == 9 and all(f.camera(1).image.mean() > 20 for f in frames)
