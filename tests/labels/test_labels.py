"""M_feat / M_match / M_hybrid labels on small hand-built feature and match tables with known answers."""

import numpy as np
import pandas as pd
import pytest

from expoctl.errors import ConfigError, InputError
from expoctl.labels.targets import LabelConfig, compute_labels


def gain_of(f, cam):  # every image has its own settings, so a target names the image it came from
    return 1.0 + f + 10.0 * (cam - 1)


def exposure_of(f, cam):
    return 1000.0 + 100.0 * f + 4000.0 * (cam - 1)


def make_tables(n_frames, sequence="s", feat=None, inl=None, gap=(), frontend="orb"):
    """Frames 0 … n−1 (minus `gap`), both cameras; feature counts default 10, inlier counts default 5."""
    feat, inl = feat or {}, inl or {}
    fids = [f for f in range(n_frames) if f not in gap]
    frames = pd.DataFrame([dict(sequence=sequence, frame_id=f, camera=c, gain_db=gain_of(f, c),
                                exposure_us=exposure_of(f, c), split="train", section="static")
                           for f in fids for c in (1, 2)])
    features = pd.DataFrame([dict(sequence=sequence, frame_id=f, camera=c, frontend=frontend,
                                  n_features=feat.get((f, c), 10)) for f in fids for c in (1, 2)])
    matches = pd.DataFrame([dict(sequence=sequence, frame_id=f, cam_from=i, cam_to=j, frontend=frontend,
                                 n_matches=100, n_inliers=inl.get((f, i, j), 5))
                            for f in fids if f + 1 in fids for i in (1, 2) for j in (1, 2)])
    return frames, features, matches


def pick(labels, metric, frame_id, sequence="s"):
    rows = labels[(labels.metric == metric) & (labels.frame_id == frame_id) & (labels.sequence == sequence)]
    assert len(rows) == 1
    return rows.iloc[0]


def test_feat_target_is_the_image_with_most_features():
    frames, features, matches = make_tables(6, feat={(3, 2): 50, (5, 1): 40, (0, 1): 999})
    labels = compute_labels(frames, features, matches)
    assert sorted(labels.frame_id.unique()) == [0, 1]  # t + 4 ≤ 5
    t0 = pick(labels, "feat", 0)  # window 1 … 4: (3, cam 2); frame 0 itself is not in its own window
    assert (t0.target_frame_id, t0.target_camera, t0.score, t0.n_tied) == (3, 2, 50, 1)
    assert (t0.gain_db, t0.exposure_us) == (gain_of(3, 2), exposure_of(3, 2))
    t1 = pick(labels, "feat", 1)  # window 2 … 5 still contains (3, 2) with 50 > 40
    assert (t1.target_frame_id, t1.target_camera) == (3, 2)
    assert t0.gain_norm == pytest.approx(gain_of(3, 2) / 30.0)
    assert t0.exposure_norm == pytest.approx((exposure_of(3, 2) - 75.0) / (30000.0 - 75.0))


def test_match_target_is_the_later_image_of_the_best_pair_cross_camera_included():
    # pair (2, cam 1) → (3, cam 2) wins for t = 0 and t = 1; for t = 2 the window starts at pair 2 → 3 too.
    frames, features, matches = make_tables(7, inl={(2, 1, 2): 80, (0, 2, 2): 70})
    labels = compute_labels(frames, features, matches)
    for t in (0, 1, 2):
        row = pick(labels, "match", t)
        assert (row.target_frame_id, row.target_camera, row.source_camera) == (3, 2, 1)
        assert (row.gain_db, row.exposure_us, row.score) == (gain_of(3, 2), exposure_of(3, 2), 80)
    # the pair (0 → 1) counts for t = 0 (b = 0 is in the window): drop the winner and (1, cam 2) is picked
    frames, features, matches = make_tables(6, inl={(0, 2, 2): 70})
    row = pick(compute_labels(frames, features, matches), "match", 0)
    assert (row.target_frame_id, row.target_camera, row.source_camera) == (1, 2, 2)


def test_ties_go_to_the_earliest_frame_then_camera_1():
    # all equal: the reference camera at t+1
    frames, features, matches = make_tables(5)
    labels = compute_labels(frames, features, matches)
    feat, match = pick(labels, "feat", 0), pick(labels, "match", 0)
    assert (feat.target_frame_id, feat.target_camera, feat.n_tied) == (1, 1, 8)
    assert (match.target_frame_id, match.target_camera, match.source_camera, match.n_tied) == (1, 1, 1, 16)
    # earliest frame beats camera 1
    frames, features, matches = make_tables(5, feat={(2, 2): 30, (3, 1): 30},
                                            inl={(1, 2, 2): 9, (2, 1, 1): 9})
    labels = compute_labels(frames, features, matches)
    assert (pick(labels, "feat", 0).target_frame_id, pick(labels, "feat", 0).target_camera) == (2, 2)
    assert (pick(labels, "match", 0).target_frame_id, pick(labels, "match", 0).target_camera) == (2, 2)
    # same frame: camera 1 beats camera 2; for pairs the target camera first, then the source camera
    frames, features, matches = make_tables(5, feat={(4, 1): 30, (4, 2): 30},
                                            inl={(3, 2, 1): 9, (3, 1, 2): 9})
    labels = compute_labels(frames, features, matches)
    assert (pick(labels, "feat", 0).target_camera, pick(labels, "feat", 0).n_tied) == (1, 2)
    m = pick(labels, "match", 0)
    assert (m.target_frame_id, m.target_camera, m.source_camera) == (4, 1, 2)
    frames, features, matches = make_tables(5, inl={(3, 2, 1): 9, (3, 1, 1): 9})
    m = pick(compute_labels(frames, features, matches), "match", 0)
    assert (m.target_camera, m.source_camera) == (1, 1)


def test_hybrid_weighted_average_linear_and_log():
    frames, features, matches = make_tables(5, feat={(2, 2): 50}, inl={(0, 1, 1): 50})
    gf, ef = gain_of(2, 2), exposure_of(2, 2)  # feat target
    gm, em = gain_of(1, 1), exposure_of(1, 1)  # match target
    h = pick(compute_labels(frames, features, matches), "hybrid", 0)
    assert (h.gain_db, h.exposure_us) == pytest.approx((0.5 * gf + 0.5 * gm, 0.5 * ef + 0.5 * em))
    assert h.gain_norm == pytest.approx(h.gain_db / 30.0)
    assert pd.isna(h.target_camera) and pd.isna(h.target_frame_id)
    cfg = {"hybrid_feat_weight": 0.25, "hybrid_exposure_average": "log"}
    h = pick(compute_labels(frames, features, matches, cfg), "hybrid", 0)
    assert h.gain_db == pytest.approx(0.25 * gf + 0.75 * gm)
    assert h.exposure_us == pytest.approx(ef**0.25 * em**0.75)
    h = pick(compute_labels(frames, features, matches, {"hybrid_feat_weight": 1.0}), "hybrid", 0)
    assert (h.gain_db, h.exposure_us) == (gf, ef)


def test_window_edges_and_gaps_give_no_label():
    # 4 frames: no complete window; columns still there
    labels = compute_labels(*make_tables(4))
    assert labels.empty and {"sequence", "frame_id", "metric", "gain_norm", "exposure_norm"} <= set(labels.columns)
    # window 1 labels every frame that has a successor
    labels = compute_labels(*make_tables(4), {"window": 1})
    assert sorted(labels.frame_id.unique()) == [0, 1, 2]
    # gap at 5 in 0 … 10: windows 0..4 and 6..10 are whole, the rest cross the gap
    labels = compute_labels(*make_tables(11, gap=(5,)))
    assert sorted(labels.frame_id.unique()) == [0, 6]
    assert list(labels.metric[:3]) == ["feat", "match", "hybrid"]


def test_sequences_do_not_leak_and_row_order_does_not_matter():
    a = make_tables(6, sequence="a", feat={(4, 2): 20})
    b = make_tables(6, sequence="b", feat={(0, 1): 500, (1, 1): 500}, inl={(0, 1, 1): 500})
    frames, features, matches = (pd.concat([x, y], ignore_index=True) for x, y in zip(a, b))
    labels = compute_labels(frames, features, matches)
    assert sorted(labels.sequence.unique()) == ["a", "b"]
    assert sorted(labels[labels.sequence == "a"].frame_id.unique()) == [0, 1]
    assert pick(labels, "feat", 1, "a").target_frame_id == 4
    assert (pick(labels, "feat", 0, "b").target_frame_id, pick(labels, "match", 0, "b").target_frame_id) == (1, 1)
    shuffled = [df.sample(frac=1.0, random_state=3).reset_index(drop=True) for df in (frames, features, matches)]
    pd.testing.assert_frame_equal(compute_labels(*shuffled), labels)


def test_frontend_selects_counts():
    frames, f_orb, m_orb = make_tables(5, feat={(1, 2): 50})
    _, f_viso, m_viso = make_tables(5, feat={(4, 2): 50}, frontend="viso")
    features, matches = pd.concat([f_orb, f_viso]), pd.concat([m_orb, m_viso])
    assert pick(compute_labels(frames, features, matches, {"frontend": "orb"}), "feat", 0).target_frame_id == 1
    assert pick(compute_labels(frames, features, matches, {"frontend": "viso"}), "feat", 0).target_frame_id == 4


def test_combined_frontend_weighs_each_relative_to_its_best():
    # t = 0, window frames 1 … 4, feature counts (ORB, viso):
    #   (1, cam 1): ORB 1000 (best) + viso 10 → 1 + 10/100 = 1.10
    #   (2, cam 2): ORB 900 + viso 100 (best) → 0.9 + 1 = 1.90   ← wins: second on ORB, best on viso
    #   default images: ORB 10, viso 10 → 0.01 + 0.1
    # A raw sum would pick (1, cam 1) (1010 vs 1000): ORB's larger counts would decide alone.
    frames, f_orb, m_orb = make_tables(5, feat={(1, 1): 1000, (2, 2): 900})
    _, f_viso, m_viso = make_tables(5, feat={(1, 1): 10, (2, 2): 100}, frontend="viso")
    features, matches = pd.concat([f_orb, f_viso]), pd.concat([m_orb, m_viso])
    row = pick(compute_labels(frames, features, matches, {"frontend": "orb+viso"}), "feat", 0)
    assert (row.target_frame_id, row.target_camera) == (2, 2)
    assert row.score == pytest.approx(1.9)
    assert pick(compute_labels(frames, features, matches, {"frontend": "orb"}), "feat", 0).target_frame_id == 1
    # matches: every pair 5 inliers on both → all candidates score 2, the tie goes to the earliest pair, camera 1
    m = pick(compute_labels(frames, features, matches, {"frontend": "orb+viso"}), "match", 0)
    assert (m.target_frame_id, m.target_camera, m.source_camera, m.score, m.n_tied) == (1, 1, 1, 2.0, 16)


def test_combined_frontend_zero_counts_contribute_nothing():
    # viso finds nothing anywhere in the window (all 0): the ORB choice stands, with a score of 1 (no 0/0 NaN)
    frames, f_orb, m_orb = make_tables(5, feat={(3, 2): 50})
    _, f_viso, m_viso = make_tables(5, feat={(f, c): 0 for f in range(5) for c in (1, 2)}, frontend="viso")
    row = pick(compute_labels(frames, pd.concat([f_orb, f_viso]), pd.concat([m_orb, m_viso]),
                              {"frontend": "orb+viso"}), "feat", 0)
    assert (row.target_frame_id, row.target_camera, row.score) == (3, 2, 1.0)


def test_combined_frontend_needs_both_frontends():
    frames, features, matches = make_tables(5)  # ORB rows only
    with pytest.raises(InputError, match="viso"):
        compute_labels(frames, features, matches, {"frontend": "orb+viso"})


@pytest.mark.parametrize("cfg, key", [
    ({"frontend": "sift"}, "labels.frontend"),
    ({"window": 0}, "labels.window"),
    ({"window": 2.5}, "labels.window"),
    ({"hybrid_feat_weight": 1.5}, "labels.hybrid_feat_weight"),
    ({"hybrid_exposure_average": "median"}, "labels.hybrid_exposure_average"),
    ({"windw": 4}, "labels.windw"),
    ({"latency_frames": 0}, "labels.latency_frames"),
    ({"latency_frames": True}, "labels.latency_frames"),
])
def test_bad_config(cfg, key):
    with pytest.raises(ConfigError) as err:
        LabelConfig.from_dict(cfg)
    assert err.value.key == key


def test_latency_shifts_the_window_by_whole_frames():
    # With latency L the window of step t is t+L … t+L+W−1: exactly the window of step t+L−1 at latency 1. So every
    # label at L = 2 equals the L = 1 label one frame later (targets, scores, ties), and the last step loses its label.
    rng = np.random.default_rng(3)
    frames, features, matches = make_tables(19)  # gain_of stays inside the camera's 30 dB
    features["n_features"] = rng.integers(0, 30, len(features))
    matches["n_inliers"] = rng.integers(0, 30, len(matches))
    one = compute_labels(frames, features, matches, {"frontend": "orb", "latency_frames": 1})
    two = compute_labels(frames, features, matches, {"frontend": "orb", "latency_frames": 2})
    assert sorted(one.frame_id.unique()) == list(range(15)) and sorted(two.frame_id.unique()) == list(range(14))
    shifted = one[one.frame_id >= 1].assign(frame_id=lambda d: d.frame_id - 1).reset_index(drop=True)
    pd.testing.assert_frame_equal(two.reset_index(drop=True), shifted)
    # the frame a latency-2 command cannot change any more (t+1) is never a target, however good it is
    frames, features, matches = make_tables(7, feat={(1, 2): 500}, inl={(0, 1, 2): 500})
    lab = compute_labels(frames, features, matches, {"latency_frames": 2})
    assert pick(lab, "feat", 0).target_frame_id >= 2 and pick(lab, "match", 0).target_frame_id >= 2
    assert pick(compute_labels(frames, features, matches), "feat", 0).target_frame_id == 1


def _raises(match, frames, features, matches, **kw):
    with pytest.raises(InputError, match=match):
        compute_labels(frames, features, matches, **kw)


def test_missing_pairing_names_sequence_and_frame():
    frames, features, matches = make_tables(6, sequence="seqX")
    drop = (matches.frame_id == 2) & (matches.cam_from == 2) & (matches.cam_to == 1)
    _raises(r"matches: sequence 'seqX', frame 2: orb pairing camera 2 → camera 1 \(frame 2 → 3\) missing",
            frames, features, matches[~drop])


def test_nan_counts_name_sequence_and_frame():
    frames, features, matches = make_tables(6, sequence="seqX")
    bad = features.copy()
    bad.loc[(bad.frame_id == 3) & (bad.camera == 2), "n_features"] = np.nan
    _raises(r"features: sequence 'seqX', frame 3, camera 2: n_features is NaN", frames, bad, matches)
    bad = matches.copy()
    bad.loc[(bad.frame_id == 1) & (bad.cam_from == 1) & (bad.cam_to == 2), "n_inliers"] = np.nan
    _raises(r"matches: sequence 'seqX', frame 1, cam_from 1, cam_to 2: n_inliers is NaN", frames, features, bad)
    bad = matches.copy()
    bad.loc[0, "n_inliers"] = -1
    _raises(r"n_inliers is NaN or negative", frames, features, bad)


def test_frame_missing_one_camera():
    frames, features, matches = make_tables(6, sequence="seqX")
    frames = frames[~((frames.frame_id == 4) & (frames.camera == 2))]
    _raises(r"frames: sequence 'seqX', frame 4: camera 2 missing", frames, features, matches)
    frames, features, matches = make_tables(6, sequence="seqX")
    features = features[~((features.frame_id == 5) & (features.camera == 1))]
    _raises(r"features: sequence 'seqX', frame 5, camera 1: no orb feature count", frames, features, matches,
            names={"features": "features"})


def test_other_bad_input():
    frames, features, matches = make_tables(6, sequence="seqX")
    _raises(r"data/frames.parquet: missing column\(s\) gain_db", frames.drop(columns="gain_db"), features, matches,
            names={"frames": "data/frames.parquet"})
    _raises(r"no rows for front end 'viso' \(present: orb\)", frames, features, matches, cfg={"frontend": "viso"})
    hot = frames.copy()
    hot.loc[3, "gain_db"] = 42.0
    _raises(r"frames: sequence 'seqX', frame 1, camera 2: gain_db is NaN or outside", hot, features, matches)
    _raises(r"frame 2, camera 1: duplicate row", pd.concat([frames, frames.iloc[[4]]]), features, matches)
    extra = pd.concat([matches, matches.iloc[[0]].assign(frame_id=5)])
    _raises(r"sequence 'seqX', frame 5: match count from frame t to t\+1, but frame t\+1 is not", frames, features,
            extra)
    extra = pd.concat([features, features.iloc[[0]].assign(frame_id=9)])
    _raises(r"frame 9, camera 1: feature count for a frame that is not in the frames table", frames, extra, matches)


def test_random_counts_match_brute_force():
    # 3 sequences × 500 frames of random counts against a brute-force argmax (speed: benchmarks/labels.py)
    rng = np.random.default_rng(0)
    tabs = [make_tables(500, sequence=f"q{k:02d}") for k in range(3)]
    frames, features, matches = (pd.concat(x, ignore_index=True) for x in zip(*tabs))
    frames["gain_db"] = rng.uniform(0, 30, len(frames))
    frames["exposure_us"] = rng.uniform(75, 30000, len(frames))
    features["n_features"] = rng.integers(0, 50, len(features))
    matches["n_inliers"] = rng.integers(0, 50, len(matches))
    labels = compute_labels(frames, features, matches)
    assert len(labels) == 3 * 3 * (500 - 4)
    # brute-force check of M_feat on a few random steps
    feat = features.set_index(["sequence", "frame_id", "camera"])["n_features"]
    for t in rng.integers(0, 496, 20):
        cands = [(feat[("q01", t + a, c)], -a, -c, t + a, c) for a in range(1, 5) for c in (1, 2)]
        best = max(cands)
        row = pick(labels, "feat", int(t), "q01")
        assert (row.target_frame_id, row.target_camera) == (best[3], best[4])
    inl = matches.set_index(["sequence", "frame_id", "cam_from", "cam_to"])["n_inliers"]
    for t in rng.integers(0, 496, 20):
        cands = [(inl[("q02", t + b, i, j)], -b, -j, -i, t + b + 1, j) for b in range(4) for i in (1, 2)
                 for j in (1, 2)]
        best = max(cands)
        row = pick(labels, "match", int(t), "q02")
        assert (row.target_frame_id, row.target_camera) == (best[4], best[5])
        g = frames.set_index(["sequence", "frame_id", "camera"])["gain_db"][("q02", best[4], best[5])]
        assert row.gain_db == g
