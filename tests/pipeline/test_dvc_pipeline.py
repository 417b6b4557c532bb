"""End to end: the whole DAG at fixture scale in a throw-away copy of the project."""

from __future__ import annotations

import json
import re

import pandas as pd
import pytest
from synthetic_raw import write_synthetic_sequence

pytestmark = pytest.mark.slow


def _ran(output: str) -> set[str]:
    return set(re.findall(r"Running stage '([\w@-]+)'", output))


ITERATION2 = {"collect_iter@2", "ingest_iter@2", "features_iter@2", "labels_iter@2", "samples_iter@2", "train_iter@2"}
ITERATION3 = {name.replace("@2", "@3") for name in ITERATION2}
ALL_STAGES = ({"compose", "collect", "ingest", "features", "labels", "samples", "train", "select_model", "evaluate",
               "report"}
              | ITERATION2 | ITERATION3)


def test_repro_noop_and_per_key_rerun(project_copy):
    p = project_copy
    # iteration 3 and the closed-loop model selection are off by default; on here so the DAG runs them
    p.set_overrides(["scale=fixture", "iteration3.enabled=true", "select_model.enabled=true"])
    first = p.dvc("repro")
    assert _ran(first.stdout) == ALL_STAGES, first.stdout
    frames = pd.read_parquet(p.root / "data" / "frames.parquet")
    assert {"sequence", "frame_id", "camera", "timestamp_ns", "gain_db", "exposure_us", "image_path", "split",
            "section"} <= set(frames.columns)
    assert len(frames) == 4 * 12 * 2  # fixture: 2 train + 1 validation + 1 test sequences of 12 frame pairs
    assert set(frames["split"]) == {"train", "validation", "test"} and "dynamic" in set(frames["section"])
    for out in ("data/features.parquet", "data/matches.parquet", "data/labels.parquet", "data/samples.parquet",
                "models/controller.pt", "models/controller.onnx", "reports/train.json", "reports/labels.md",
                "models/controller_iter2.pt", "reports/iter2/train.json", "models/controller_iter3.pt",
                "reports/iter3/train.json", "models/controller_final.pt", "models/controller_final.onnx",
                "reports/select_model.json", "reports/metrics.json", "reports/headline.json",
                "reports/eval/frames.parquet", "reports/results.md"):
        assert (p.root / out).is_file(), out
    metrics = json.loads((p.root / "reports" / "metrics.json").read_text())
    assert set(metrics) == {"validation", "test"}
    for split in metrics.values():
        assert set(split) == {"agae", "shin", "shim", "mean_intensity", "fixed", "learned", "oracle"}
        for entry in split.values():
            assert set(entry["dynamic"]) == {"orb", "viso", "orb_sumlog", "viso_sumlog"}
            n_ok, n_runs = entry["tracking_success"]
            assert 0 <= n_ok <= n_runs and n_runs >= 1
    assert list((p.root / "reports" / "figures").glob("*.png"))
    # the one DVC metric: a dozen headline numbers that agree with the full tables
    headline = json.loads((p.root / "reports" / "headline.json").read_text())
    assert headline["dynamic_min_nfm"]["test"]["viso"]["agae"] == metrics["test"]["agae"]["dynamic"]["viso"]["min_nfm"]
    n_ok = sum(metrics[city]["learned"]["tracking_success"][0] for city in metrics)
    assert headline["vo_tracked"]["learned"]["frame_to_frame"] == n_ok
    shown = json.loads(p.dvc("metrics", "show", "--json").stdout)
    assert [list(v["data"]) for v in shown.values()] == [["reports/headline.json"]], shown
    # iteration 2: one more training sequence driven by the iteration-1 network, trained on both data sets
    frames2 = pd.read_parquet(p.root / "data" / "iter2" / "frames.parquet")
    assert set(frames["sequence"]) < set(frames2["sequence"])
    assert frames2["sequence"].nunique() == frames["sequence"].nunique() + 1
    # iteration 3: one more, driven by the iteration-2 network, trained on all three data sets
    frames3 = pd.read_parquet(p.root / "data" / "iter3" / "frames.parquet")
    assert set(frames2["sequence"]) < set(frames3["sequence"])
    assert frames3["sequence"].nunique() == frames2["sequence"].nunique() + 1
    # select_model drove all three iterations' networks and AG+AE; the final model is the chosen one's bytes
    selection = json.loads((p.root / "reports" / "select_model.json").read_text())
    assert [c["name"] for c in selection["candidates"]] == ["iteration1", "iteration2", "iteration3"]
    assert [s["name"] for s in selection["scores"]] == ["iteration1", "iteration2", "iteration3"]
    assert selection["reference_statistics"]["name"] == "agae" and len(selection["runs"]) == 4
    chosen = next(c for c in selection["candidates"] if c["name"] == selection["chosen"])
    # collect_iter@2's reference gate ran select_model's probe on the same network: the same verdict, to the bit
    gate = json.loads((p.root / "reports" / "iter2" / "collect_reference.json").read_text())
    probed = selection["probe"]["results"]["iteration1"]
    assert gate["probe"]["worst_saturated_frac"] == probed["worst_saturated_frac"]
    assert gate["reference_controller"] == ("learned" if probed["passes"] else "agae")
    assert (p.root / "models" / "controller_final.pt").read_bytes() == (p.root / chosen["path"]).read_bytes()
    assert p.stage_runs() == {s: 1 for s in ALL_STAGES}
    assert p.stage_runs(children=True) == {"evaluate": 7 * 2}  # one per (controller, city), for the MLflow UI

    # Bytecode that an import or a test run leaves in a source directory (another interpreter's, say) is not a
    # change of the code: the second repro stays a no-op.
    bytecode = p.root / "src" / "expoctl" / "world" / "__pycache__"
    bytecode.mkdir(exist_ok=True)
    (bytecode / "stray.cpython-399.pyc").write_bytes(b"\0" * 16)
    second = p.dvc("repro")
    assert _ran(second.stdout) == set(), second.stdout

    # Switching iteration 3 off re-runs exactly the iteration-3 stages and the selection; evaluate re-runs exactly when
    # the selection's final network changed (it depends on the network, not on the iteration keys; which candidate
    # wins is the selection's measured outcome, not something this test fixes).
    final_before = (p.root / "models" / "controller_final.pt").read_bytes()
    p.set_overrides(["scale=fixture", "iteration3.enabled=false", "select_model.enabled=true"])
    third = p.dvc("repro")
    final_changed = (p.root / "models" / "controller_final.pt").read_bytes() != final_before
    assert _ran(third.stdout) == ({"compose", "select_model", "report"} | ITERATION3
                                  | ({"evaluate"} if final_changed else set())), third.stdout
    model2 = (p.root / "models" / "controller_iter2.pt").read_bytes()
    assert (p.root / "models" / "controller_iter3.pt").read_bytes() == model2
    assert pd.read_parquet(p.root / "data" / "iter3" / "frames.parquet").equals(frames2)
    selection = json.loads((p.root / "reports" / "select_model.json").read_text())
    assert [c["name"] for c in selection["candidates"]] == ["iteration1", "iteration2"]

    # A key no stage reads except compose: only compose re-runs (its output changes, but no stage's keys do).
    p.set_overrides(["scale=fixture", "iteration3.enabled=false", "select_model.enabled=true", "+unused_note=hello"])
    fourth = p.dvc("repro")
    assert _ran(fourth.stdout) == {"compose"}, fourth.stdout
    # A leaf key (the report's layout): compose and report only.
    p.set_overrides(["scale=fixture", "iteration3.enabled=false", "select_model.enabled=true", "+unused_note=hello",
                     "report.strip_columns=4"])
    assert _ran(p.dvc("repro").stdout) == {"compose", "report"}
    runs = p.stage_runs()
    assert runs["report"] == 3 and runs["evaluate"] == 1 + final_changed and runs["select_model"] == 2
    assert runs["compose"] == 4 and runs["train"] == 1 and runs["train_iter@2"] == 1 and runs["train_iter@3"] == 2


def test_bad_raw_data_stops_cleanly(project_copy):
    """A real rig recording with a bad cell, ingested on its own (collect not run): a one-line message, no output."""
    p = project_copy
    seq = write_synthetic_sequence(p.root / "data" / "raw" / "train" / "s", n_frames=3)
    (seq / "frames.csv").write_text((seq / "frames.csv").read_text().replace("3.0,", "99.0,", 1))
    p.dvc("repro", "compose")
    out = p.dvc("repro", "--single-item", "ingest", check=False)
    assert out.returncode != 0
    assert "line 2, column 'gain_db': 99.0 outside the valid range" in out.stderr + out.stdout
    assert "Traceback" not in out.stderr
    assert not (p.root / "data" / "frames.parquet").exists()
