"""compute_features on small generated sequences: schema, exact agreement with direct calls, n_jobs invariance,
single extraction per image, and clear errors for bad input."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import skimage.data

from expoctl.errors import ConfigError, InputError
from expoctl.features import pipeline
from expoctl.features.orb import OrbFrontEnd
from expoctl.features.pipeline import (
    FEATURES_COLUMNS,
    MATCHES_COLUMNS,
    compute_features,
    match_images,
    pair_seed,
    read_grey,
    rgb_to_grey,
)
from expoctl.io import write_png

ORB = {"working_size": None, "count_nfeatures": 400, "match_nfeatures": 200}
PARAMS = {"frontends": ["orb"], "orb": ORB, "seed": 3}
W, H = 240, 180


def _frame(photo, t, cam):
    """A camera panning 5 px/frame over a photo; camera 2 sits 2 px to the right and runs 1.6x brighter."""
    x0 = 5 * t + (2 if cam == 2 else 0)
    crop = photo[40 : 40 + H, x0 : x0 + W].astype(np.float64)
    return np.clip(crop * (1.6 if cam == 2 else 1.0), 0, 255).astype(np.uint8)


def make_project(root: Path, n_frames=4, sequences=("seq_a", "seq_b")):
    photos = {"seq_a": skimage.data.astronaut(), "seq_b": skimage.data.coffee()}
    rows = []
    for s in sequences:
        for t in range(n_frames):
            for cam in (1, 2):
                rel = f"data/raw/{s}/cam{cam}/{t:06d}.png"
                write_png(_frame(photos[s], t, cam), root / rel)
                rows.append({"sequence": s, "frame_id": t, "camera": cam, "image_path": rel, "split": "train"})
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("proj")
    return root, make_project(root)


@pytest.fixture(scope="module")
def computed(project):
    root, frames = project
    return compute_features(frames, root, PARAMS, n_jobs=1, progress=False)


def test_schema_and_row_counts(computed):
    feats, matches = computed
    assert list(feats.columns) == FEATURES_COLUMNS and list(matches.columns) == MATCHES_COLUMNS
    assert len(feats) == 2 * 4 * 2  # sequences × frames × cameras (one front end)
    assert len(matches) == 2 * 3 * 4  # sequences × (frames − 1) × the four camera pairings
    assert set(zip(matches.cam_from, matches.cam_to)) == {(1, 1), (1, 2), (2, 1), (2, 2)}
    assert matches.groupby("sequence").frame_id.max().tolist() == [2, 2]  # frame_id is the earlier frame t
    for col in ("frame_id", "camera", "n_features"):
        assert feats[col].dtype == np.int64
    assert (matches.n_inliers <= matches.n_matches).all()
    assert (matches.n_inliers > 50).all()  # every pairing sees the same photo moved a few px


def test_values_equal_direct_front_end_calls(project, computed):
    root, frames = project
    feats, matches = computed
    orb = OrbFrontEnd(ORB)
    path = lambda t, cam: root / f"data/raw/seq_b/cam{cam}/{t:06d}.png"  # noqa: E731
    a, b = orb.extract(read_grey(path(1, 2))), orb.extract(read_grey(path(2, 1)))
    row = matches.query("sequence == 'seq_b' and frame_id == 1 and cam_from == 2 and cam_to == 1").iloc[0]
    assert (row.n_matches, row.n_inliers) == orb.match(a, b, pair_seed(3, "seq_b", 1, 2, 1, "orb"))
    f = feats.query("sequence == 'seq_b' and frame_id == 1 and camera == 2").n_features.item()
    assert f == orb.n_features(a)


def test_process_pool_gives_identical_results(project, computed):
    root, frames = project
    feats2, matches2 = compute_features(frames, root, PARAMS, n_jobs=2, progress=False)
    pd.testing.assert_frame_equal(feats2, computed[0])
    pd.testing.assert_frame_equal(matches2, computed[1])


def test_each_image_extracted_once(project, monkeypatch):
    root, frames = project
    calls = {"extract": 0, "match": 0}

    class Counting(OrbFrontEnd):
        def extract(self, grey):
            calls["extract"] += 1
            return super().extract(grey)

        def match(self, prev, cur, seed):
            calls["match"] += 1
            return super().match(prev, cur, seed)

    monkeypatch.setattr(pipeline, "_FRONTEND_CACHE", {})
    monkeypatch.setattr(pipeline, "make_frontend", lambda name, params=None: Counting(params))
    compute_features(frames, root, PARAMS, n_jobs=1, progress=False)
    assert calls == {"extract": 16, "match": 24}


def test_pair_seed_is_stable_and_specific():
    s = pair_seed(0, "seq_a", 10, 1, 2, "orb")
    assert s == pair_seed(0, "seq_a", 10, 1, 2, "orb") and 0 <= s < 2**31
    others = {pair_seed(0, "seq_a", 10, 2, 1, "orb"), pair_seed(0, "seq_a", 11, 1, 2, "orb"),
              pair_seed(1, "seq_a", 10, 1, 2, "orb"), pair_seed(0, "seq_a", 10, 1, 2, "viso")}
    assert s not in others and len(others) == 4
    assert pair_seed(0, "seq_a", 10, 1, 2, "orb") == 472619662  # blake2b: the same on every platform and run


def test_grey_from_file_equals_grey_from_array(tmp_path):
    rgb = skimage.data.astronaut()[:50, :60]
    write_png(rgb, tmp_path / "a.png")
    assert np.array_equal(read_grey(tmp_path / "a.png"), rgb_to_grey(rgb))


# ---------------------------------------------------------------------------------------------------- bad input


def _fresh(tmp_path, **kw):
    frames = make_project(tmp_path, n_frames=3, sequences=("seq_a",), **kw)
    return tmp_path, frames


def test_unreadable_image_names_the_file(tmp_path):
    root, frames = _fresh(tmp_path)
    (root / "data/raw/seq_a/cam2/000001.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match=r"seq_a/cam2/000001\.png: unreadable"):
        compute_features(frames, root, PARAMS, n_jobs=1, progress=False)


def test_unreadable_image_in_a_worker_process(tmp_path):
    root, frames = _fresh(tmp_path)
    frames = pd.concat([frames, frames.assign(sequence="seq_c")], ignore_index=True)  # two tasks → the pool runs
    (root / "data/raw/seq_a/cam1/000002.png").unlink()
    with pytest.raises(InputError, match=r"seq_a/cam1/000002\.png: image file missing"):
        compute_features(frames, root, PARAMS, n_jobs=2, progress=False)


def test_size_mismatch_names_both_files(tmp_path):
    root, frames = _fresh(tmp_path)
    write_png(np.zeros((H, W + 8, 3), np.uint8), root / "data/raw/seq_a/cam1/000002.png")
    with pytest.raises(InputError, match=r"cam1/000002\.png: image is 248×180 but .*cam1/000000\.png.* is 240×180"):
        compute_features(frames, root, PARAMS, n_jobs=1, progress=False)


def test_missing_next_frame_of_one_camera(tmp_path):
    root, frames = _fresh(tmp_path)
    frames = frames[~((frames.frame_id == 2) & (frames.camera == 2))]
    with pytest.raises(InputError, match="sequence seq_a frame 2: camera 2 image missing"):
        compute_features(frames, root, PARAMS, n_jobs=1, progress=False)


def test_gap_in_frame_ids(tmp_path):
    root, frames = _fresh(tmp_path)
    frames = frames[frames.frame_id != 1]
    with pytest.raises(InputError, match="sequence seq_a: frame 1 missing"):
        compute_features(frames, root, PARAMS, n_jobs=1, progress=False)


@pytest.mark.parametrize(
    "mutate, message",
    [
        (lambda f: f.drop(columns="image_path"), "missing column"),
        (lambda f: f.iloc[:0], "no rows"),
        (lambda f: pd.concat([f, f.iloc[:1]]), "appears twice"),
        (lambda f: f.assign(camera=f.camera.replace(2, 3)), "camera must be 1 or 2"),
        (lambda f: f.assign(frame_id=[0, 0.5]), "row 1: column frame_id must be an integer"),
        (lambda f: f.assign(image_path=["a", None]), "row 1: column image_path is empty"),
    ],
)
def test_bad_frames_table(tmp_path, mutate, message):
    frames = pd.DataFrame({"sequence": ["s"] * 2, "frame_id": [0, 0], "camera": [1, 2], "image_path": ["a", "b"]})
    with pytest.raises(InputError, match=message):
        compute_features(mutate(frames), tmp_path, PARAMS, n_jobs=1, progress=False)


@pytest.mark.parametrize(
    "cfg, key",
    [
        ({"frontends": ["sift"]}, "features.frontends"),
        ({"frontends": "orb"}, "features.frontends"),
        ({"n_jobs": 2}, "features.n_jobs"),  # moved to parallel.n_jobs (2026-12-07)
        ({"threads": 2}, "features.threads"),
        ({"orb": {"nfeatures": 10}}, "features.orb.nfeatures"),
    ],
)
def test_bad_config(tmp_path, cfg, key):
    frames = pd.DataFrame({"sequence": ["s"], "frame_id": [0], "camera": [1], "image_path": ["a"]})
    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        compute_features(frames, tmp_path, {**PARAMS, **cfg}, progress=False)


def test_match_images_checks_sizes():
    orb = OrbFrontEnd(ORB)
    with pytest.raises(InputError, match="sizes differ"):
        match_images(orb, np.zeros((10, 20), np.uint8), np.zeros((10, 21), np.uint8))
    grey = rgb_to_grey(skimage.data.astronaut())
    counts = match_images(orb, grey, grey)
    assert counts.n_features_prev == counts.n_features_cur == 400 and counts.n_inliers == counts.n_matches == 200


def test_training_pairs_for_sumlog(project):
    root, frames = project
    pairs = list(pipeline.iter_training_pairs_rgb(frames, root, camera=1, max_pairs=4))
    assert len(pairs) == 4  # seq_a: (0,1) (1,2) (2,3), then seq_b (0,1)
    assert pairs[0][0].shape == (H, W, 3)
    assert np.array_equal(pairs[0][1], pairs[1][0])  # consecutive pairs share the middle frame


def test_with_viso_front_end_when_available(project):
    pytest.importorskip("expoctl.features.viso")
    root, frames = project
    frames = frames[(frames.sequence == "seq_a") & (frames.frame_id <= 1)]
    feats, matches = compute_features(frames, root, {**PARAMS, "frontends": ["orb", "viso"]}, n_jobs=1, progress=False)
    assert sorted(feats.frontend.unique()) == ["orb", "viso"] and len(feats) == 8 and len(matches) == 8
    viso = matches[matches.frontend == "viso"]
    assert (viso.n_inliers > 0).all() and (viso.n_inliers <= viso.n_matches).all()
