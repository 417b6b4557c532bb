import numpy as np
import pytest

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN
from expoctl.controllers.base import Settings
from expoctl.errors import ConfigError
from expoctl.rig.protocol import PerturbationConfig, perturb, quadrant


def test_quadrant_cycle_visits_all_four_every_four_frames():
    first = [quadrant(t) for t in range(4)]
    assert sorted(first) == [(-1, -1), (-1, 1), (1, -1), (1, 1)]
    for t in range(40):
        assert quadrant(t) == first[t % 4]


def test_perturbation_signs_follow_quadrant_and_stay_within_half():
    ref = Settings(12.0, 4000.0)
    for seed in range(5):
        for t in range(64):
            g_sign, e_sign = quadrant(t)
            p = perturb(ref, t, seed)
            g_ratio = p.gain_db / ref.gain_db
            e_ratio = p.exposure_us / ref.exposure_us
            # multiplied by 1 ± U[0, 0.5]: the sign decides the side of 1, the magnitude is at most 0.5
            assert (g_ratio - 1.0) * g_sign >= 0.0 and abs(g_ratio - 1.0) <= 0.5 + 1e-12
            assert (e_ratio - 1.0) * e_sign >= 0.0 and abs(e_ratio - 1.0) <= 0.5 + 1e-12


def test_perturbation_fractions_cover_the_range():
    ref = Settings(10.0, 1000.0)
    fracs = np.array([abs(perturb(ref, t, 3).exposure_us / 1000.0 - 1.0) for t in range(400)])
    # U[0, 0.5]: mean 0.25, both ends reached
    assert abs(fracs.mean() - 0.25) < 0.03
    assert fracs.min() < 0.02 and fracs.max() > 0.48


def test_zero_gain_adds_in_up_quadrants_and_stays_in_down_quadrants():
    cfg = PerturbationConfig(zero_gain_add_db=(1.0, 6.0))
    ref = Settings(0.0, 800.0)
    for t in range(32):
        p = perturb(ref, t, 11, cfg)
        if quadrant(t)[0] > 0:
            assert 1.0 <= p.gain_db <= 6.0
        else:
            assert p.gain_db == 0.0
    every = PerturbationConfig(zero_gain_add_in_down_quadrants=True)
    assert all(1.0 <= perturb(ref, t, 11, every).gain_db <= 6.0 for t in range(32))


def test_clamped_to_camera_ranges():
    hi = Settings(GAIN_DB_MAX, EXPOSURE_US_MAX)
    lo = Settings(GAIN_DB_MIN, EXPOSURE_US_MIN)
    for t in range(16):
        for ref in (hi, lo):
            p = perturb(ref, t, 0)
            assert GAIN_DB_MIN <= p.gain_db <= GAIN_DB_MAX
            assert EXPOSURE_US_MIN <= p.exposure_us <= EXPOSURE_US_MAX
    # up-quadrant at the top of the range is clamped exactly to the maximum
    assert perturb(hi, 0, 0).exposure_us == EXPOSURE_US_MAX
    assert perturb(hi, 0, 0).gain_db == GAIN_DB_MAX


def test_deterministic_per_seed_and_frame():
    ref = Settings(7.0, 2500.0)
    assert perturb(ref, 17, 5) == perturb(ref, 17, 5)
    assert perturb(ref, 17, 5) != perturb(ref, 17, 6)
    # a frame's draw does not depend on the frames before it
    seq = [perturb(ref, t, 5) for t in range(20)]
    assert seq[17] == perturb(ref, 17, 5)


@pytest.mark.parametrize(
    "bad, key",
    [
        ({"max_fraction": 1.5}, "rig.perturbation.max_fraction"),
        ({"max_fraction": "x"}, "rig.perturbation.max_fraction"),
        ({"zero_gain_add_db": [6, 1]}, "rig.perturbation.zero_gain_add_db"),
        ({"zero_gain_add_db": 3}, "rig.perturbation.zero_gain_add_db"),
        ({"zero_gain_add_in_down_quadrants": "yes"}, "rig.perturbation.zero_gain_add_in_down_quadrants"),
        ({"max_fractoin": 0.5}, "rig.perturbation.max_fractoin"),
    ],
)
def test_bad_config_names_the_key(bad, key):
    with pytest.raises(ConfigError) as e:
        PerturbationConfig.from_dict(bad)
    assert e.value.key == key


def test_config_round_trip():
    cfg = PerturbationConfig.from_dict({"max_fraction": 0.4, "zero_gain_add_db": [2, 5]})
    assert PerturbationConfig.from_dict(cfg.to_dict()) == cfg
