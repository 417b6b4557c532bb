"""Label report statistics on hand-built data with known answers, and the labels stage end to end."""

import json

import numpy as np
import pandas as pd
import pytest

from expoctl.camera.ranges import exposure_value_ev
from expoctl.errors import InputError
from expoctl.labels.report import compute_label_stats, flat_metrics, render_markdown
from expoctl.labels.targets import compute_labels
from fake_tracker import FakeTracker


def rig_tables(n_frames=8):
    """Camera 1: gain = frame id dB, 1000 µs. Camera 2: same gain, exposure 2000 µs on even frames (+1 EV) and 500 µs
    on odd ones (−1 EV). Features: the brighter camera 2 images have most (20 > 10 > 5). Matches: 1 → 1 pairs win."""
    frames, features, matches = [], [], []
    for f in range(n_frames):
        for c in (1, 2):
            exp = 1000.0 if c == 1 else (2000.0 if f % 2 == 0 else 500.0)
            frames.append(dict(sequence="s", frame_id=f, camera=c, gain_db=float(f), exposure_us=exp,
                               split="train", section="static" if f < 4 else "dynamic"))
            features.append(dict(sequence="s", frame_id=f, camera=c, frontend="orb",
                                 n_features=10 if c == 1 else (20 if f % 2 == 0 else 5)))
        if f + 1 < n_frames:
            for i in (1, 2):
                for j in (1, 2):
                    matches.append(dict(sequence="s", frame_id=f, cam_from=i, cam_to=j, frontend="orb",
                                        n_matches=50, n_inliers=30 if i == j == 1 else 5))
    return pd.DataFrame(frames), pd.DataFrame(features), pd.DataFrame(matches)


def test_stats_on_hand_built_rig():
    frames, features, matches = rig_tables()
    labels = compute_labels(frames, features, matches)
    stats = compute_label_stats(labels, frames, {"frontend": "orb", "window": 4})
    feat, match, hybrid = (stats["metrics"][m] for m in ("feat", "match", "hybrid"))
    assert stats["n_labelled_time_steps"] == 4 and feat["n"] == 4
    # feat targets: t = 0, 1 → (2, cam 2); t = 2, 3 → (4, cam 2); all +1 EV over camera 1 at the same frame
    assert feat["camera_share"] == {"1": 0.0, "2": 1.0}
    assert feat["ev_offset_same_frame"]["median"] == pytest.approx(1.0)
    assert feat["ev_offset_same_frame"]["share_brighter"] == 1.0
    assert feat["ev_offset_same_frame_camera2_targets"]["median"] == pytest.approx(1.0)
    assert feat["gain_offset_db_same_frame"]["median"] == 0.0
    assert feat["consecutive_same_image"] == pytest.approx(2 / 3)
    assert feat["consecutive_equal_settings"] == pytest.approx(2 / 3)
    # vs camera 1 at t+1: +1 EV of exposure plus the gain difference (target frame − (t+1)) dB
    ev_next = [1 + (2 - 1) / 6.0206, 1 + 0.0, 1 + (4 - 3) / 6.0206, 1 + 0.0]
    assert feat["ev_offset_next_reference"]["mean"] == pytest.approx(np.mean(ev_next), abs=1e-4)
    assert feat["tie_share"] == 1.0  # every window holds two even camera-2 frames with 20: the earlier one wins
    # match targets: (t+1, camera 1), i.e. exactly the reference; all consecutive settings differ (gain rises)
    assert match["camera_share"] == {"1": 1.0, "2": 0.0}
    assert match["cross_camera_pair_share"] == 0.0
    assert match["ev_offset_same_frame"]["median"] == 0.0 and match["ev_offset_next_reference"]["median"] == 0.0
    assert match["consecutive_equal_settings"] == 0.0
    # target moves: feat 0, +2 dB, 0 between steps; match follows camera 1's +1 dB per frame
    assert feat["consecutive_abs_ev_change"]["median"] == 0.0
    assert match["consecutive_abs_ev_change"]["median"] == pytest.approx(1 / 6.0206)
    assert stats["camera1_abs_ev_step"]["median"] == pytest.approx(1 / 6.0206)
    # hybrid: half of each → exposure 1500 µs, gain the mean of the two
    t0 = labels[(labels.metric == "hybrid") & (labels.frame_id == 0)].iloc[0]
    assert t0.exposure_us == 1500.0 and t0.gain_db == 1.5
    assert hybrid["ev_offset_next_reference"]["n"] == 4
    expected = exposure_value_ev(1.5, 1500.0) - exposure_value_ev(1.0, 1000.0)
    assert hybrid["ev_offset_next_reference"]["p10"] <= expected <= hybrid["ev_offset_next_reference"]["p90"]
    assert hybrid["feat_match_same_image_share"] == 0.0
    # the perturbation camera 2 − camera 1 over all 8 frames: ±1 EV, half brighter
    pert = stats["perturbation_ev_camera2_minus_camera1"]
    assert pert["share_brighter"] == 0.5 and pert["mean"] == pytest.approx(0.0)
    assert set(stats["by_section"]) == {"static"}  # labelled t = 0 … 3, all in the static section
    assert stats["by_section"]["static"]["feat"]["n"] == 4
    # findings say both observations of the paper hold here
    text = " ".join(stats["findings"])
    assert "reference camera in 100% of time steps" in text and text.count("— consistent") == 2
    assert stats["findings"][2].endswith("NOT consistent.")  # here feat targets stay put more often than match
    md = render_markdown(stats)
    assert "| from camera 1 / 2 | 0% / 100% | 100% / 0% | — |" in md
    assert "+1.00 (+1.00 … +1.00) EV" in md
    assert flat_metrics(stats)["feat.camera2_share"] == 1.0
    json.dumps(stats)  # serialisable as is


def test_findings_flag_disagreement():
    frames, features, matches = rig_tables()
    matches["n_inliers"] = np.where((matches.cam_to == 2) & (matches.cam_from == 1), 40, 5)  # camera 2 wins
    features["n_features"] = np.where(features.camera == 1, 30, 5)  # reference has most features
    stats = compute_label_stats(compute_labels(frames, features, matches), frames)
    assert stats["metrics"]["match"]["camera_share"]["2"] == 1.0
    assert stats["metrics"]["match"]["cross_camera_pair_share"] == 1.0
    assert stats["metrics"]["feat"]["camera_share"]["1"] == 1.0
    # match targets now alternate between the ±1 EV camera-2 images, feat targets follow camera 1's +1 dB per frame
    assert stats["metrics"]["match"]["consecutive_abs_ev_change"]["median"] == pytest.approx(2.0 + 1 / 6.0206)
    assert stats["metrics"]["feat"]["consecutive_abs_ev_change"]["median"] == pytest.approx(1 / 6.0206)
    assert all("NOT consistent" in line for line in stats["findings"])


def test_no_labels_still_reports():
    frames, features, matches = rig_tables(4)
    labels = compute_labels(frames, features, matches)
    stats = compute_label_stats(labels, frames)
    assert stats["n_labelled_time_steps"] == 0
    assert "every window was incomplete" in stats["findings"][0]
    assert "# Label report" in render_markdown(stats)


def stage_cfg(tmp_path):
    paths = {k: str(tmp_path / f"data/{k}.parquet") for k in ("frames", "features", "matches", "labels", "samples")}
    paths["reports_dir"] = str(tmp_path / "reports")
    return {"paths": paths, "labels": {"frontend": "orb", "window": 4, "hybrid_feat_weight": 0.5,
                                       "hybrid_exposure_average": "linear"}, "samples": {"metric": "hybrid"}}


def test_labels_stage_writes_table_and_report(tmp_path):
    from stages.labels import run

    cfg = stage_cfg(tmp_path)
    (tmp_path / "data").mkdir()
    for name, df in zip(("frames", "features", "matches"), rig_tables()):
        df.to_parquet(cfg["paths"][name])
    tracker = FakeTracker()
    run(cfg, tracker)
    labels = pd.read_parquet(cfg["paths"]["labels"])
    assert len(labels) == 12 and set(labels.metric) == {"feat", "match", "hybrid"}
    report = json.loads((tmp_path / "reports/labels.json").read_text())
    assert report["metrics"]["feat"]["camera_share"]["2"] == 1.0
    assert (tmp_path / "reports/labels.md").read_text().startswith("# Label report")
    assert tracker.params["effective.labels"]["frontend"] == "orb"
    assert tracker.metrics["match.camera2_share"] == 0.0
    assert sorted(p.rsplit("/", 1)[-1] for p in tracker.artifacts) == ["labels.json", "labels.md"]

    # then the samples stage on its output
    from stages.samples import run as run_samples

    run_samples(cfg, tracker)
    samples = pd.read_parquet(cfg["paths"]["samples"])
    assert len(samples) == 2 * 8  # labelled t = 0 … 3, of which t = 2, 3 have t−1 and t−2
    assert tracker.metrics["n_samples"] == 16 and tracker.metrics["train"]["n_samples"] == 16


def test_labels_stage_bad_input_leaves_old_output(tmp_path):
    from stages.labels import run

    cfg = stage_cfg(tmp_path)
    (tmp_path / "data").mkdir()
    frames, features, matches = rig_tables()
    frames.to_parquet(cfg["paths"]["frames"])
    matches.to_parquet(cfg["paths"]["matches"])
    with pytest.raises(InputError, match=r"features.parquet: missing; run the features stage first"):
        run(cfg, FakeTracker())
    features.iloc[1:].to_parquet(cfg["paths"]["features"])  # frame 0, camera 1 has no count
    (tmp_path / "data/labels.parquet").write_text("old")
    with pytest.raises(InputError, match=r"features.parquet: sequence 's', frame 0, camera 1: no orb feature count"):
        run(cfg, FakeTracker())
    assert (tmp_path / "data/labels.parquet").read_text() == "old"
    assert not (tmp_path / "reports").exists()
    for name, df in zip(("frames", "features", "matches"), rig_tables(4)):  # too short for one window
        df.to_parquet(cfg["paths"][name])
    with pytest.raises(InputError, match=r"no time step has a complete window t\+1 … t\+4 \(4 frames"):
        run(cfg, FakeTracker())
    assert (tmp_path / "data/labels.parquet").read_text() == "old"


def test_findings_explain_brighter_match_targets():
    frames, features, matches = rig_tables()
    # pairs into an even (+1 EV) camera-2 frame win: the matcher prefers the brighter image
    matches["n_inliers"] = np.where((matches.cam_to == 2) & (matches.frame_id % 2 == 1), 40, 5)
    stats = compute_label_stats(compute_labels(frames, features, matches), frames)
    assert stats["metrics"]["match"]["ev_offset_same_frame_camera2_targets"]["median"] == pytest.approx(1.0)
    assert "winning camera-2 images are brighter than the reference (median +1.00 EV)" in stats["findings"][0]
