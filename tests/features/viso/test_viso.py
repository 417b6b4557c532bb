"""libviso2-style front end: parameters, interface, and parity with the original's reference numbers (spec §10)."""

import json
from pathlib import Path

import numpy as np
import pytest

from expoctl.errors import ConfigError, InputError
from expoctl.features.viso import VisoFrontEnd, extract_features, match_matches, pair_counts
from expoctl.features.viso.params import parse_params
from expoctl.features.viso.ransac import ransac_inlier_count


def _reference_dir():
    d = Path(__file__).resolve().parents[4] / "shared" / "data" / "viso_reference"  # ../shared beside the repository
    return d if (d / "reference.jsonl").exists() else None


REF_DIR = _reference_dir()


def _textured(seed=0, shape=(240, 320), shift=(0, 0)):
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (shape[0] // 4 + 4, shape[1] // 4 + 4), dtype=np.uint8)
    img = np.kron(base, np.ones((4, 4), np.uint8))  # blocky texture: strong blobs and corners
    dy, dx = shift
    return np.ascontiguousarray(img[8 + dy : 8 + dy + shape[0], 8 + dx : 8 + dx + shape[1]])


@pytest.mark.parametrize(
    "params,key",
    [
        ({"nms_n": 0}, "features.viso.nms_n"),
        ({"nms_tau": 2.5}, "features.viso.nms_tau"),
        ({"match_radius": True}, "features.viso.match_radius"),
        ({"refinement": 2}, "features.viso.refinement"),
        ({"multi_stage": "yes"}, "features.viso.multi_stage"),
        ({"inlier_threshold": 0}, "features.viso.inlier_threshold"),
        ({"ransac_iter": 100}, "features.viso.ransac_iter"),
    ],
)
def test_bad_params_name_the_key(params, key):
    with pytest.raises(ConfigError) as e:
        VisoFrontEnd(params)
    assert e.value.key == key


def test_params_defaults_and_sparse_block_size():
    p = parse_params(None)
    assert (p.nms_n, p.sparse_nms_n, p.search_radius, p.bucketing) == (3, 9, 100.0, False)
    assert parse_params({"nms_n": 4}).sparse_nms_n == 10  # 12 > 10 → max(4, 10)
    assert parse_params({"nms_n": 2}).sparse_nms_n == 6
    assert parse_params({"half_resolution": 0}).search_radius == 200.0


def test_extract_rejects_non_grey_input():
    fe = VisoFrontEnd()
    with pytest.raises(InputError):
        fe.extract(np.zeros((40, 40, 3), np.uint8))
    with pytest.raises(InputError):
        fe.extract(np.zeros((40, 40), np.float32))


def test_match_rejects_different_sizes():
    fe = VisoFrontEnd()
    with pytest.raises(InputError):
        fe.match(fe.extract(_textured()), fe.extract(_textured(shape=(200, 320))), seed=0)


def test_features_are_even_full_resolution_positions_inside_the_margin():
    img = _textured()
    f = extract_features(img, parse_params(None))
    d = f.dense
    assert len(d) > 100 and len(f.sparse) < len(d)
    assert (d.u % 2 == 0).all() and (d.v % 2 == 0).all()
    # matching resolution 160×120, n = 3, margin 9: positions in [12, 150] × [12, 110], i.e. 24 … 2W′−20 at full res
    assert d.u.min() >= 24 and d.u.max() <= 300 and d.v.min() >= 24 and d.v.max() <= 220


def test_translated_image_matches_and_is_deterministic_per_seed():
    fe = VisoFrontEnd()
    a = fe.extract(_textured(shift=(0, 0)))
    b = fe.extract(_textured(shift=(4, 6)))  # pure translation: content moves by (−6, −4) px
    n_matches, n_inliers = fe.match(a, b, seed=3)
    assert n_matches > 100
    assert n_inliers >= 0.9 * n_matches
    assert fe.match(a, b, seed=3) == (n_matches, n_inliers)
    assert fe.n_features(a) == len(a.dense)
    counts = pair_counts(a, b, seed=3)
    assert counts.n_raw_matches == n_matches and counts.n_inliers_nobucket == n_inliers
    assert counts.n_inliers <= counts.n_bucketed <= 2 * ((320 // 50) + 1) * ((240 // 50) + 1)
    # bucketing switches n_inliers to count B
    assert VisoFrontEnd({"bucketing": True}).match(a, b, seed=3) == (n_matches, counts.n_inliers)


def _reference_rows():
    if REF_DIR is None:
        return []
    return [json.loads(line) for line in (REF_DIR / "reference.jsonl").read_text().splitlines() if line.strip()]


@pytest.mark.parametrize("ref", _reference_rows() or [None], ids=lambda r: r["prev"] if r else "absent")
def test_parity_with_the_original(ref):
    if ref is None:
        pytest.skip("reference data ../shared/data/viso_reference is absent")
    import cv2

    fe = VisoFrontEnd()
    prev = fe.extract(cv2.imread(str(REF_DIR / ref["prev"]), cv2.IMREAD_GRAYSCALE))
    cur = fe.extract(cv2.imread(str(REF_DIR / ref["cur"]), cv2.IMREAD_GRAYSCALE))
    got = pair_counts(prev, cur, seed=0).as_dict()
    exact = ["n_features_1", "n_features_2", "n_features_sparse_1", "n_features_sparse_2", "n_sparse_circular",
             "n_dense_circular", "n_dense_after_refinement"]  # fmt: skip
    assert {k: got[k] for k in exact} == {k: ref[k] for k in exact}
    # Delaunay ties (co-circular points on the even lattice) are broken differently by Qhull and Triangle: 0.5 %,
    # with an allowance of 2 matches for pairs whose final count is tiny
    for key in ("n_sparse_after_outliers", "n_raw_matches", "n_bucketed"):
        assert abs(got[key] - ref[key]) <= max(0.005 * ref[key], 2), key
    # count C depends on RANSAC sampling: compare the mean over 5 seeds (absolute allowance 3 for tiny counts)
    p = parse_params(None)
    matches, _ = match_matches(prev, cur, p)
    assert len(matches) == got["n_raw_matches"]
    c_mean = np.mean([ransac_inlier_count(matches, p.ransac_iters, p.inlier_threshold, s) for s in range(5)])
    assert abs(c_mean - ref["n_inliers_nobucket"]) <= max(0.05 * ref["n_inliers_nobucket"], 3)
    # count B (bucketed): the reference is one draw of the original's own spread (basketball: 97–111 over 10
    # seeds, reference 99), so its mean is compared within 10 %
    b_mean = np.mean([pair_counts(prev, cur, seed=s).n_inliers for s in range(5)])
    assert abs(b_mean - ref["n_inliers"]) <= max(0.10 * ref["n_inliers"], 3)


@pytest.mark.parametrize(
    "params", [{"multi_stage": False}, {"refinement": 0}, {"half_resolution": False}, {"nms_n": 2, "nms_tau": 30}]
)
def test_pipeline_variants_match_a_translation(params):
    fe = VisoFrontEnd(params)
    a = fe.extract(_textured(shift=(0, 0)))
    b = fe.extract(_textured(shift=(4, 6)))
    n_matches, n_inliers = fe.match(a, b, seed=1)
    assert n_matches > 100
    assert n_inliers >= 0.9 * n_matches
    if params.get("half_resolution") is False:
        assert (a.dense.u % 2 == 1).any()  # matching at full resolution: odd positions occur
