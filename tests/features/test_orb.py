"""ORB front end on real photographs (scikit-image sample data, bundled with the package)."""

import cv2
import numpy as np
import pytest
import skimage.data

from expoctl.errors import ConfigError
from expoctl.features.frontend import FrontEnd
from expoctl.features.orb import OrbFrontEnd, OrbParams, hamming_mutual_matches


def _grey(rgb):
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)


@pytest.fixture(scope="module")
def stereo():
    left, right, _ = skimage.data.stereo_motorcycle()  # a real rectified stereo pair, 500×741
    return _grey(left), _grey(right)


@pytest.fixture(scope="module")
def orb():
    return OrbFrontEnd({})


def test_conforms_to_the_front_end_interface(orb):
    for attr in ("name", "extract", "n_features", "match"):
        assert hasattr(orb, attr), attr
    _typed: FrontEnd = orb  # static conformance (FrontEnd is a typing.Protocol, not runtime-checkable)
    assert orb.name == "orb"


def test_two_detectors_count_and_match_caps(stereo):
    small = OrbFrontEnd({"count_nfeatures": 300, "match_nfeatures": 100})
    feats = small.extract(stereo[0])
    # a textured 500×741 photo has far more than 300 FAST corners, so both detectors fill their caps
    assert small.n_features(feats) == 300
    assert feats.points_xy.shape == (100, 2) and feats.descriptors.shape == (100, 32)


def test_resizes_to_the_working_size(stereo, orb):
    feats = orb.extract(stereo[0])
    assert orb.prepare(stereo[0]).shape == (384, 512)
    assert feats.points_xy[:, 0].max() < 512 and feats.points_xy[:, 1].max() < 384
    native = OrbFrontEnd({"working_size": None})
    assert native.prepare(stereo[0]) is stereo[0]


def test_real_stereo_pair_has_mostly_inlier_matches(stereo, orb):
    a, b = orb.extract(stereo[0]), orb.extract(stereo[1])
    n_matches, n_inliers = orb.match(a, b, seed=0)
    # cross-check keeps mutual nearest neighbours only; between the two views of one static scene most are right
    assert 500 <= n_matches <= 2000
    assert n_inliers >= 0.6 * n_matches


def test_unrelated_images_have_few_inliers(orb):
    a = orb.extract(skimage.data.camera())
    b = orb.extract(_grey(skimage.data.coffee()))
    n_matches, n_inliers = orb.match(a, b, seed=0)
    assert n_matches > 100
    # matches between unrelated photos are random; the best F collects only those that happen to fall within 3 px
    # of its epipolar lines (a few %) — far below the > 60 % of a real pair
    assert n_inliers <= 0.15 * n_matches


def test_translated_crop_keeps_every_correct_match():
    astro = _grey(skimage.data.astronaut())
    prev, cur = astro[0:384, 0:480], astro[10:394, 16:496]  # the camera moved by (16, 10) px: content moves (-16, -10)
    orb = OrbFrontEnd({"working_size": None})
    a, b = orb.extract(prev), orb.extract(cur)
    n_matches, n_inliers = orb.match(a, b, seed=0)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    ms = matcher.match(a.descriptors, b.descriptors)
    shift = np.array([b.points_xy[m.trainIdx] - a.points_xy[m.queryIdx] for m in ms])
    n_correct = int(np.sum(np.linalg.norm(shift - [-16, -10], axis=1) < 1.5))
    assert n_matches == len(ms) and n_correct > 1000
    # correct matches all satisfy one geometry; ORB keypoints are quantised per pyramid level (up to ~1 px at the
    # coarser levels), well inside 3 px, so at most a few percent may be missed
    assert n_inliers >= 0.98 * n_correct
    assert n_inliers <= n_matches


def test_deterministic(stereo):
    a1, a2 = OrbFrontEnd({}), OrbFrontEnd({})
    x, y = a1.extract(stereo[0]), a2.extract(stereo[0])
    assert x.n_count == y.n_count and np.array_equal(x.points_xy, y.points_xy)
    assert np.array_equal(x.descriptors, y.descriptors)
    b = a1.extract(stereo[1])
    assert a1.match(x, b, seed=5) == a2.match(y, a2.extract(stereo[1]), seed=5)


def test_featureless_image_gives_zero(orb, stereo):
    flat = orb.extract(np.full((480, 640), 128, np.uint8))
    assert orb.n_features(flat) == 0
    assert orb.match(flat, orb.extract(stereo[0]), seed=0) == (0, 0)


def test_rejects_non_grey_input(orb):
    with pytest.raises(ValueError, match="grey"):
        orb.extract(np.zeros((48, 64, 3), np.uint8))


@pytest.mark.parametrize(
    "cfg, key",
    [
        ({"nfeatures": 5}, "features.orb.nfeatures"),
        ({"working_size": [512]}, "features.orb.working_size"),
        ({"count_nfeatures": 0}, "features.orb.count_nfeatures"),
        ({"scale_factor": 1.0}, "features.orb.scale_factor"),
        ({"fast_threshold": 300}, "features.orb.fast_threshold"),
        ({"ransac_threshold_px": -1}, "features.orb.ransac_threshold_px"),
    ],
)
def test_bad_config_names_the_key(cfg, key):
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        OrbParams.from_dict(cfg)


def test_config_round_trip():
    p = OrbParams.from_dict({"working_size": [320, 240], "match_nfeatures": 500})
    assert p.working_size == (320, 240) and p.match_nfeatures == 500 and p.count_nfeatures == 10000


def test_mutual_matcher_on_a_constructed_example():
    bits = lambda *on: np.packbits(np.isin(np.arange(256), on)).reshape(1, 32)  # noqa: E731  32-byte descriptor
    a = np.concatenate([bits(), bits(0, 1, 2), bits(100, 101)])
    b = np.concatenate([bits(0, 1, 2, 3), bits(100, 101), bits(200)])
    # distances a×b: a0: 4,2,1 → b2; a1: 1,5,4 → b0; a2: 6,0,3 → b1.  b2's nearest a is a0 (1) → all mutual
    ia, ib = hamming_mutual_matches(a, b)
    assert ia.tolist() == [0, 1, 2] and ib.tolist() == [2, 0, 1]
    # a lone candidate wanted by two queries: only its own nearest (ties → lower index) is kept
    ia, ib = hamming_mutual_matches(np.concatenate([bits(7), bits(7)]), bits(7, 8))
    assert ia.tolist() == [0] and ib.tolist() == [0]
    # non-multiple-of-8 descriptor width and empty input
    ia, ib = hamming_mutual_matches(np.array([[1, 2, 3]], np.uint8), np.array([[1, 2, 7], [0, 0, 0]], np.uint8))
    assert ia.tolist() == [0] and ib.tolist() == [0]
    assert hamming_mutual_matches(np.zeros((0, 32), np.uint8), b)[0].size == 0


def test_mutual_matcher_equals_opencv_cross_check(stereo, orb):
    a, b = orb.extract(stereo[0]), orb.extract(stereo[1])
    ia, ib = hamming_mutual_matches(a.descriptors, b.descriptors)
    cv_matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(a.descriptors, b.descriptors)
    assert set(zip(ia.tolist(), ib.tolist())) == {(m.queryIdx, m.trainIdx) for m in cv_matches}


def test_mutual_matcher_equals_opencv_cross_check_with_ties_and_order():
    """The VO trackers take this matcher's pairs in its order (RANSAC samples them by index), so it must give
    OpenCV's BFMatcher(crossCheck=True) list exactly, order included, also where distances tie: descriptors drawn
    from a few distinct bit patterns, from few active bits, and random ones with copied rows."""
    rng = np.random.default_rng(7)
    n_ties = 0
    for trial in range(240):
        na, nb = (int(v) for v in rng.integers(1, 50, 2))
        if trial % 3 == 0:  # few active bits: many equal distances
            mask = rng.integers(0, 2, (1, 32))
            a = (rng.integers(0, 2, (na, 32)) * mask).astype(np.uint8)
            b = (rng.integers(0, 2, (nb, 32)) * mask).astype(np.uint8)
        elif trial % 3 == 1:  # random, half of b copies rows of a
            a = rng.integers(0, 256, (na, 32), dtype=np.uint8)
            b = rng.integers(0, 256, (nb, 32), dtype=np.uint8)
            b[: min(na, nb) // 2] = a[: min(na, nb) // 2]
        else:  # three patterns only: every row has exact duplicates
            base = rng.integers(0, 256, (3, 32), dtype=np.uint8)
            a, b = base[rng.integers(0, 3, na)], base[rng.integers(0, 3, nb)]
        d = np.unpackbits(a[:, None, :] ^ b[None, :, :], axis=2).sum(axis=2)
        n_ties += int(np.any((d == d.min(axis=1, keepdims=True)).sum(axis=1) > 1))
        ia, ib = hamming_mutual_matches(a, b)
        cv_matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(a, b)
        assert list(zip(ia.tolist(), ib.tolist())) == [(m.queryIdx, m.trainIdx) for m in cv_matches], trial
    assert n_ties > 100  # the tie rule was really exercised
