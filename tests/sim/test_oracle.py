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
    from expoctl.controllers.registry import CONTROLLERS

    assert CONTROLLERS.get("oracle").info["needs"] == ("scene",)
    with pytest.raises(ConfigError, match="simulator"):
        make_controller("oracle", {})


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


# ------------------------------------------------------------------ candidates at the matching size (candidate_render)


class CoarseScene:
    """moving_scene plus luminance_coarse: the k×k block mean of the full luminance (what a coarse render of a
    texture this smooth would give), recording every request."""

    def __init__(self, level):
        self.inner = moving_scene(level)
        self.full_requests, self.coarse_requests = [], []

    def luminance(self, frame, exposure_us, camera):
        self.full_requests.append((frame, exposure_us))
        return self.inner.luminance(frame, exposure_us, camera)

    def luminance_coarse(self, frame, exposure_us, camera, factor):
        self.coarse_requests.append((frame, exposure_us, factor))
        lum = self.inner.luminance(frame, exposure_us, camera)
        h, w = lum.shape[0] // factor, lum.shape[1] // factor
        return lum.reshape(h, factor, w, factor, 3).mean(axis=(1, 3)).astype(np.float32)

    def timestamp_ns(self, frame):
        return self.inner.timestamp_ns(frame)


def test_bad_candidate_render_names_the_key():
    with pytest.raises(ConfigError, match="controllers.oracle.candidate_render"):
        OracleParams.from_dict({"candidate_render": "half"})
    assert OracleParams.from_dict({"candidate_render": "match"}).candidate_render == "match"


@pytest.mark.parametrize("size, match_width, factor", [((640, 480), 320, 2), ((640, 480), 300, 2),
                                                       ((640, 480), 200, 2), ((160, 120), 96, 1),
                                                       ((100, 75), 30, 1), ((160, 120), 40, 4)])
def test_coarse_factor_is_the_largest_divisor_not_below_the_matching_width(size, match_width, factor):
    # 640 / 200 → 3 does not divide 640, so 2; 100×75 / 30 → 3 does not divide 100 and 2 not 75, so 1
    oracle = OracleController(CachedScene(CoarseScene(lambda f: 1000.0)), LinearSensor(), 0, n_frames=10,
                              params=OracleParams(match_width=match_width, candidate_render="match"))
    assert oracle._coarse_factor(*size) == factor
    full = OracleController(CachedScene(CoarseScene(lambda f: 1000.0)), LinearSensor(), 0, n_frames=10,
                            params=OracleParams(match_width=match_width, candidate_render="full"))
    assert full._coarse_factor(*size) == 1
    # a scene that cannot render coarse: full size whatever the setting
    plain = OracleController(CachedScene(moving_scene(lambda f: 1000.0)), LinearSensor(), 0, n_frames=10,
                             params=OracleParams(match_width=match_width, candidate_render="match"))
    assert plain._coarse_factor(*size) == 1


def test_match_scores_coarse_candidates_with_the_real_noise_and_delivers_full_frames():
    level = lambda f: 1000.0 if f < 6 else 20000.0  # noqa: E731
    inner = CoarseScene(level)
    scene = CachedScene(inner)
    sensor = LinearSensor(noise_dn=2.0)
    params = OracleParams(match_width=80, match_nfeatures=500, objective="match", candidate_render="match")
    oracle = OracleController(scene, sensor, 5, n_frames=100, first_frame=0, params=params)
    frames = list(run_closed_loop(scene, [sensor], oracle, Settings(0.0, 5000.0), range(0, 8), 5))
    # every candidate came from a coarse render at 160/80 = 2; every delivered frame from a full one
    exps = set(params.exposures_us)
    assert {e for _, e, _ in inner.coarse_requests} == exps and {k for *_, k in inner.coarse_requests} == {2}
    assert len(inner.coarse_requests) == len(exps) * len(oracle.choices)
    delivered = [(f.frame_index, f.camera(1).settings.exposure_us) for f in frames]
    assert sorted(inner.full_requests) == sorted(delivered)
    # the oracle's inlier count for its choice is that of frame t (full) against the candidate image it scored:
    # the coarse luminance replicated 2×2, captured with frame t+1's noise
    from expoctl.sim.closed_loop import sensor_rng

    fe = oracle._frontend((120, 160))
    images = {f.frame_index: f.camera(1).image for f in frames}
    for t1, chosen, n_inl, _ in oracle.choices[2:]:
        if t1 >= 8:
            continue
        coarse = inner.luminance_coarse(t1, chosen.exposure_us, 1, 2)
        lum = np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)
        img = sensor.capture(lum, chosen.exposure_us, chosen.gain_db, sensor_rng(5, 1, t1))
        assert fe.match(fe.extract(rgb_to_grey(images[t1 - 1])), fe.extract(rgb_to_grey(img)), t1)[1] == n_inl
