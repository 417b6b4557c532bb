"""Samples: eight camera combinations per labelled time step with history, scaled targets, split by sequence."""

import numpy as np
import pandas as pd
import pytest

from expoctl.errors import ConfigError, InputError
from expoctl.labels.samples import COMBINATIONS, SampleConfig, build_samples, sample_id, summarise_samples
from fake_tracker import FakeTracker


def frames_table(n_frames, sequence="s", split="train", gap=()):
    return pd.DataFrame([dict(sequence=sequence, frame_id=f, camera=c, gain_db=3.0 * c, exposure_us=1000.0 * c,
                              split=split, section="static")
                         for f in range(n_frames) if f not in gap for c in (1, 2)])


def labels_table(sequence, frame_ids, metrics=("feat", "match", "hybrid")):
    rows = []
    for f in frame_ids:
        for k, m in enumerate(metrics):
            rows.append(dict(sequence=sequence, frame_id=f, metric=m, gain_db=float(f + k),
                             exposure_us=75.0 + 100.0 * (f + k)))
    return pd.DataFrame(rows)


def test_eight_combinations_per_labelled_step_with_history():
    frames = frames_table(8)
    labels = labels_table("s", range(0, 4))  # t = 0, 1 lack t−1 / t−2
    samples = build_samples(frames, labels)
    assert sorted(samples.frame_id.unique()) == [2, 3]
    assert len(samples) == 2 * 8
    t2 = samples[samples.frame_id == 2]
    assert [tuple(r) for r in t2[["cam_t", "cam_t1", "cam_t2"]].to_numpy()] == [tuple(c) for c in COMBINATIONS]
    assert len({tuple(c) for c in COMBINATIONS}) == 8
    # hybrid label of t = 2: gain 2 + 2 = 4 dB, exposure 75 + 400 µs
    assert np.allclose(t2.target_gain_norm, 4.0 / 30.0)
    assert np.allclose(t2.target_exposure_norm, 400.0 / (30000.0 - 75.0))
    assert set(samples.split) == {"train"} and set(samples.metric) == {"hybrid"}
    assert samples.sample_id.is_unique
    assert t2.sample_id.iloc[5] == sample_id("s", 2, 2, 1, 2) == "s/000002/c212"


def test_metric_choice_and_gap_in_history():
    frames = frames_table(10, gap=(4,))
    labels = labels_table("s", range(10))
    labels = labels[labels.frame_id != 4]
    samples = build_samples(frames, labels, {"metric": "feat"})
    # 5 needs 4 and 3; 6 needs 5 and 4 → both dropped
    assert sorted(samples.frame_id.unique()) == [2, 3, 7, 8, 9]
    assert np.allclose(samples[samples.frame_id == 7].target_gain_norm, 7.0 / 30.0)  # feat: k = 0


def test_split_by_sequence_and_deterministic():
    frames = pd.concat([frames_table(6, "a", "train"), frames_table(6, "b", "validation"),
                        frames_table(6, "c", "test")], ignore_index=True)
    labels = pd.concat([labels_table(s, range(2, 6)) for s in "abc"], ignore_index=True)
    samples = build_samples(frames, labels)
    assert samples.groupby("sequence")["split"].unique().map(list).to_dict() == {
        "a": ["train"], "b": ["validation"], "c": ["test"]}
    again = build_samples(frames.sample(frac=1.0, random_state=1), labels.sample(frac=1.0, random_state=2))
    pd.testing.assert_frame_equal(samples, again)
    summary = summarise_samples(samples)
    assert summary["validation"] == {"n_samples": 32, "n_time_steps": 4, "n_sequences": 1}


def test_empty_labels_give_empty_samples_with_columns():
    samples = build_samples(frames_table(3), labels_table("s", [0]))
    assert samples.empty
    assert {"sample_id", "cam_t", "cam_t1", "cam_t2", "target_gain_norm", "target_exposure_norm", "split"} <= set(
        samples.columns)


def test_bad_input():
    frames = pd.concat([frames_table(6, "a", "train"), frames_table(6, "b", "test")], ignore_index=True)
    labels = labels_table("a", range(2, 6))
    mixed = frames.copy()
    mixed.loc[(mixed.sequence == "b") & (mixed.frame_id == 3), "split"] = "train"
    with pytest.raises(InputError, match=r"sequence 'b' appears in several splits \(test, train\)"):
        build_samples(mixed, labels)
    odd = frames.copy()
    odd.loc[0, "split"] = "holdout"
    with pytest.raises(InputError, match=r"frames: sequence 'a', frame 0: split must be one of"):
        build_samples(odd, labels)
    with pytest.raises(InputError, match=r"labels: sequence 'a', frame 9: label for a frame that is not in"):
        build_samples(frames, labels_table("a", [9]))
    bad = labels.copy()
    bad.loc[bad.metric == "hybrid", "gain_db"] = np.nan
    with pytest.raises(InputError, match=r"labels: sequence 'a', frame 2: gain_db is NaN"):
        build_samples(frames, bad)
    with pytest.raises(InputError, match=r"no labels for metric 'hybrid' \(present: feat\)"):
        build_samples(frames, labels_table("a", [2], metrics=("feat",)))
    with pytest.raises(InputError, match=r"frames: sequence 'a', frame 2: camera 2 missing"):
        build_samples(frames.drop(index=5), labels)
    with pytest.raises(ConfigError, match="samples.metric"):
        SampleConfig.from_dict({"metric": "best"})


def test_samples_stage(tmp_path):
    from stages.samples import run

    paths = {"frames": str(tmp_path / "frames.parquet"), "labels": str(tmp_path / "labels.parquet"),
             "samples": str(tmp_path / "samples.parquet")}
    cfg = {"paths": paths, "samples": {"metric": "match"}}
    frames_table(6, "a", "validation").to_parquet(paths["frames"])
    labels_table("a", [0, 1]).to_parquet(paths["labels"])
    with pytest.raises(InputError, match=r"labels.parquet: no labelled time step t has frames t−1 and t−2"):
        run(cfg, FakeTracker())
    assert not (tmp_path / "samples.parquet").exists()
    labels_table("a", range(6)).to_parquet(paths["labels"])
    tracker = FakeTracker()
    run(cfg, tracker)
    samples = pd.read_parquet(paths["samples"])
    assert len(samples) == 4 * 8 and set(samples.metric) == {"match"} and set(samples.split) == {"validation"}
    assert np.allclose(samples[samples.frame_id == 5].target_gain_norm, 6.0 / 30.0)  # match label: f + 1
    assert tracker.params["effective.samples"] == {"metric": "match"}
    assert tracker.metrics["validation"]["n_time_steps"] == 4 and tracker.metrics["n_samples"] == 32
