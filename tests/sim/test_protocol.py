import numpy as np
import pytest

from expoctl.camera.ranges import EXPOSURE_US_MAX, EXPOSURE_US_MIN, GAIN_DB_MAX, GAIN_DB_MIN, SENSOR_EXPOSURE_US_MIN
from expoctl.controllers.base import Settings
from expoctl.errors import ConfigError
from expoctl.sim.protocol import PerturbationConfig, excursion_offset_ev, perturb, quadrant


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
            assert SENSOR_EXPOSURE_US_MIN <= p.exposure_us <= EXPOSURE_US_MAX  # camera 2 may go below the network's range
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
        ({"excursion_probability": 1.5}, "rig.perturbation.excursion_probability"),
        ({"excursion_ev": [5, 2]}, "rig.perturbation.excursion_ev"),
        ({"excursion_ev": [0, 2]}, "rig.perturbation.excursion_ev"),
        ({"excursion_frames": 0}, "rig.perturbation.excursion_frames"),
        ({"excursion_frames": 2.5}, "rig.perturbation.excursion_frames"),
    ],
)
def test_bad_config_names_the_key(bad, key):
    with pytest.raises(ConfigError) as e:
        PerturbationConfig.from_dict(bad)
    assert e.value.key == key


def test_config_round_trip():
    cfg = PerturbationConfig.from_dict({"max_fraction": 0.4, "zero_gain_add_db": [2, 5], "excursion_ev": [1, 3]})
    assert PerturbationConfig.from_dict(cfg.to_dict()) == cfg


def _product_ev(s: Settings) -> float:
    return float(np.log2(s.exposure_us) + s.gain_db / (20 * np.log10(2)))


def test_no_excursions_by_default_is_the_paper_protocol():
    assert all(excursion_offset_ev(t, 3, PerturbationConfig()) == 0.0 for t in range(200))


def test_excursions_hold_for_a_block_and_scale_the_product():
    cfg = PerturbationConfig(excursion_probability=0.5, excursion_ev=(2.0, 5.0), excursion_frames=6)
    offsets = np.array([excursion_offset_ev(t, 3, cfg) for t in range(6000)])
    blocks = offsets.reshape(-1, 6)
    assert (blocks == blocks[:, :1]).all()  # one offset per 6-frame block
    on = blocks[:, 0] != 0.0
    assert 0.45 < on.mean() < 0.55  # 1000 blocks at p = 0.5 (seeded; one standard error is 0.016)
    size = np.abs(blocks[on, 0])
    assert size.min() >= 2.0 and size.max() <= 5.0
    assert 0.4 < (blocks[on, 0] > 0).mean() < 0.6  # both signs
    # inside the camera ranges the product moves by exactly the offset, exposure time first
    ref = Settings(0.0, 1000.0)
    t = int(np.flatnonzero(offsets > 0)[0])
    out = perturb(ref, t, 3, cfg)
    assert _product_ev(out) - _product_ev(ref) == pytest.approx(offsets[t])
    assert out.gain_db == 0.0 and out.exposure_us == pytest.approx(1000.0 * 2 ** offsets[t])
    # exposure at its upper limit: the rest of the offset goes to gain
    tunnel = Settings(6.0, EXPOSURE_US_MAX)
    out = perturb(tunnel, t, 3, cfg)
    assert out.exposure_us == EXPOSURE_US_MAX
    assert out.gain_db == pytest.approx(min(GAIN_DB_MAX, 6.0 + offsets[t] * 20 * np.log10(2)))
    # outside excursions the quadrant cycle is unchanged
    t0 = int(np.flatnonzero(offsets == 0.0)[0])
    assert perturb(ref, t0, 3, cfg) == perturb(ref, t0, 3, PerturbationConfig())
