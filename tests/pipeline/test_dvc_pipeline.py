"""End to end: the whole DAG at fixture scale in a throw-away copy of the project."""

from __future__ import annotations

import json
import os
import re

import fixture_manifest
import pandas as pd
import pytest
import yaml
from synthetic_raw import write_synthetic_sequence

pytestmark = pytest.mark.slow


def _ran(output: str) -> set[str]:
    return set(re.findall(r"Running stage '([\w@-]+)'", output))


ITERATION2 = {"collect_iter@2", "ingest_iter@2", "features_iter@2", "labels_iter@2", "samples_iter@2", "train_iter@2"}
ITERATION3 = {name.replace("@2", "@3") for name in ITERATION2}
# guard runs on every repro (always changed) and writes nothing but its stamp; it logs no MLflow run
# train_rl is off by default: it runs and writes only its marker models/rl/DISABLED.json
ALL_STAGES = ({"guard", "compose", "collect", "ingest", "features", "labels", "samples", "train", "select_model", "evaluate",
               "report", "train_rl"}
              | ITERATION2 | ITERATION3)


def test_repro_noop_and_per_key_rerun(project_copy):
    p = project_copy
    # iteration 3 and the closed-loop model selection are off by default; on here so the DAG runs them
    p.set_overrides(fixture_manifest.OVERRIDES)
    first = p.dvc("repro")
    assert _ran(first.stdout) == ALL_STAGES, first.stdout
    # Same bytes on every host: in the pinned numeric mode (the default) this run must reproduce the committed
    # manifest, whatever CI host's CPU ran it (tests/pipeline/fixture_manifest.py names the exceptions and why).
    _check_manifest(p.root)
    # the README's commands to compare experiments fit in 120 columns (a bare `dvc exp show` is ~410 wide)
    shown = p.dvc("exp", "show", "--md", "--drop", ".*", "--keep", "^(Experiment|overrides|val_loss)$").stdout
    rows = shown.strip().splitlines()
    assert max(map(len, rows)) <= 120, shown
    assert [c.strip() for c in rows[0].strip("|").split("|")] == ["Experiment", "val_loss", "overrides"], shown
    assert "iteration3.enabled=true" in shown, shown
    diff = p.dvc("metrics", "diff", "--all").stdout
    assert max(map(len, diff.splitlines())) <= 120, diff
    for key in ("val_loss", "dynamic_min_nfm.test.viso.learned", "vo_tracked.agae.map", "vo_tracked.learned.runs"):
        assert key in diff, diff
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
    assert p.stage_runs() == {s: 1 for s in ALL_STAGES - {"guard"}}
    assert p.stage_runs(children=True) == {"evaluate": 7 * 2}  # one per (controller, city), for the MLflow UI

    # Bytecode that an import or a test run leaves in a source directory (another interpreter's, say) is not a
    # change of the code: the second repro stays a no-op.
    bytecode = p.root / "src" / "expoctl" / "world" / "__pycache__"
    bytecode.mkdir(exist_ok=True)
    (bytecode / "stray.cpython-399.pyc").write_bytes(b"\0" * 16)
    second = p.dvc("repro")
    assert _ran(second.stdout) == {"guard"}, second.stdout

    # Where and how fast the jobs run is not a result: the finished run pointed at a Ray cluster, with another worker
    # count, re-runs nothing but compose, which writes the new `parallel` block into configs/resolved.yaml. No stage
    # declares it as a param (a runtime key, stages/table.py), so `dvc status` then has nothing to re-run, and the
    # cluster is never contacted.
    p.set_overrides(fixture_manifest.OVERRIDES + ["parallel.backend=ray", "parallel.address=127.0.0.1:1",
                                                  "parallel.n_jobs=2"])
    moved = p.dvc("repro")
    assert _ran(moved.stdout) == {"guard", "compose"}, moved.stdout
    resolved = yaml.safe_load((p.root / "configs" / "resolved.yaml").read_text())
    assert resolved["parallel"] == {"backend": "ray", "address": "127.0.0.1:1", "n_jobs": 2}
    assert _status_stages(p.dvc("status").stdout) <= {"guard"}  # guard is always changed, by design

    # Switching iteration 3 off re-runs exactly the iteration-3 stages and the selection; evaluate re-runs exactly when
    # the selection's final network changed (it depends on the network, not on the iteration keys; which candidate
    # wins is the selection's measured outcome, not something this test fixes).
    final_before = (p.root / "models" / "controller_final.pt").read_bytes()
    p.set_overrides(["scale=fixture", "iteration3.enabled=false", "select_model.enabled=true"])
    third = p.dvc("repro")
    final_changed = (p.root / "models" / "controller_final.pt").read_bytes() != final_before
    assert _ran(third.stdout) == ({"guard", "compose", "select_model", "report"} | ITERATION3
                                  | ({"evaluate"} if final_changed else set())), third.stdout
    model2 = (p.root / "models" / "controller_iter2.pt").read_bytes()
    assert (p.root / "models" / "controller_iter3.pt").read_bytes() == model2
    assert pd.read_parquet(p.root / "data" / "iter3" / "frames.parquet").equals(frames2)
    selection = json.loads((p.root / "reports" / "select_model.json").read_text())
    assert [c["name"] for c in selection["candidates"]] == ["iteration1", "iteration2"]

    # params.yaml changed, every stage's keys the same (the overrides reordered): only compose re-runs.
    p.set_overrides(["select_model.enabled=true", "scale=fixture", "iteration3.enabled=false"])
    fourth = p.dvc("repro")
    assert _ran(fourth.stdout) == {"guard", "compose"}, fourth.stdout
    # A leaf key (the report's layout): compose and report only.
    p.set_overrides(["select_model.enabled=true", "scale=fixture", "iteration3.enabled=false", "report.strip_columns=4"])
    assert _ran(p.dvc("repro").stdout) == {"guard", "compose", "report"}
    runs = p.stage_runs()
    assert runs["report"] == 3 and runs["evaluate"] == 1 + final_changed and runs["select_model"] == 2
    assert runs["compose"] == 5 and runs["train"] == 1 and runs["train_iter@2"] == 1 and runs["train_iter@3"] == 2


def _check_manifest(root):
    """The run's outputs against tests/pipeline/fixture_manifest.json (or, with EXPOCTL_WRITE_FIXTURE_MANIFEST=1,
    the manifest rewritten from this run), and its record of the numeric mode: pinned before any import."""
    from expoctl.numerics import NumericsConfig, environment

    record = json.loads((root / "reports" / "numerics.json").read_text())
    assert record["mode"] == "pinned" and record["applied_before_import"], record
    assert {k: v for k, v in record["environment"].items() if v is not None} == environment(NumericsConfig("pinned"))
    if os.environ.get(fixture_manifest.WRITE_ENV) == "1":
        fixture_manifest.write(root)
        return
    diff = fixture_manifest.differences(root)
    assert not diff, ("the fixture DAG's outputs differ from tests/pipeline/fixture_manifest.json (if the change is "
                      f"meant to change them, regenerate: {fixture_manifest.REGENERATE}):\n" + "\n".join(diff))


def _status_stages(status: str) -> set[str]:
    """The stages `dvc status` lists as changed (its unindented 'name:' lines)."""
    return {line[:-1] for line in status.splitlines() if line.endswith(":") and not line[:1].isspace()}


def test_bad_raw_data_stops_cleanly(project_copy):
    """A real rig recording with a bad cell in its home: `dvc repro` stops at collect (which validates recordings
    before copying them) with a message naming file, line and column; no output, the recording untouched."""
    p = project_copy
    seq = _recording(p.root / "data" / "recordings" / "train" / "s", n_frames=3, seed=0)
    (seq / "frames.csv").write_text((seq / "frames.csv").read_text().replace("3.0,", "99.0,", 1))
    before = _tree(seq)
    p.set_overrides(["scale=fixture", "collect.source=recordings"])
    out = p.dvc("repro", "ingest", check=False)
    assert out.returncode != 0
    assert "line 2, column 'gain_db': 99.0 outside the valid range" in out.stderr + out.stdout
    assert "Traceback" not in out.stderr
    assert not (p.root / "data" / "raw").exists() and not (p.root / "data" / "frames.parquet").exists()
    assert _tree(seq) == before


def _recording(seq_dir, n_frames: int, seed: int):
    """A real-rig-style sequence (`source: rig`) in the raw format."""
    seq = write_synthetic_sequence(seq_dir, n_frames=n_frames, height=120, width=160, seed=seed)
    (seq / "sequence.yaml").write_text((seq / "sequence.yaml").read_text().replace("source: sim", "source: rig"))
    return seq


def _tree(d):
    return {p.relative_to(d).as_posix(): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def _interrupt_when(p, args: list[str], marker: bytes, timeout_s: float = 300.0):
    """Run `dvc <args>` in its own process group, send SIGINT to the group (a Ctrl-C) as soon as `marker` shows in
    its output, again every 3 s while it runs on, and return (exit code, output)."""
    import os
    import signal
    import subprocess
    import sys
    import threading
    import time

    proc = subprocess.Popen([sys.executable, "-m", "dvc", *args], cwd=p.root, env=p.env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, start_new_session=True)
    chunks: list[bytes] = []
    reader = threading.Thread(target=lambda: chunks.extend(iter(lambda: os.read(proc.stdout.fileno(), 4096), b"")))
    reader.start()
    deadline = time.monotonic() + timeout_s
    while marker not in b"".join(chunks):
        assert proc.poll() is None and time.monotonic() < deadline, b"".join(chunks).decode()[-3000:]
        time.sleep(0.05)
    # a Ctrl-C that lands while numba's compiler is inside a ctypes callback is swallowed there ("Exception ignored
    # on calling ctypes callback function"), and the stage runs on: press it again, as a user would
    for _ in range(20):
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=3)
            break
        except subprocess.TimeoutExpired:
            continue
    proc.wait(timeout=120)
    reader.join()
    return proc.returncode, b"".join(chunks).decode(errors="replace")


def test_recordings_train_and_last_good_outputs_survive(project_copy):
    """Real recordings in their home train the network with nothing simulated and are never touched; a recording
    put where the old docs said (data/raw) stops `dvc repro` before anything runs; a bad value and a Ctrl-C mid-stage
    leave every previous output in place, and the messages say so."""
    p = project_copy
    rec = p.root / "data" / "recordings"
    for i, split in enumerate(("train", "train", "validation")):
        _recording(rec / split / f"rig_{i:03d}", n_frames=24, seed=i)
    recordings = _tree(rec)
    base = ["scale=fixture", "collect.source=recordings"]
    p.set_overrides(base)
    first = p.dvc("repro", "train")
    assert _ran(first.stdout) == {"guard", "compose", "collect", "ingest", "features", "labels", "samples", "train"}
    assert "nothing simulated" in first.stdout + first.stderr
    frames = pd.read_parquet(p.root / "data" / "frames.parquet")
    assert set(frames["sequence"]) == {"rig_000", "rig_001", "rig_002"} and len(frames) == 3 * 24 * 2
    assert _tree(rec) == recordings
    # the copy collect made, swapped in whole: the sequences (not the home's README)
    assert _tree(p.root / "data" / "raw") == {k: v for k, v in recordings.items() if k != "README.md"}

    # 1. where the old docs said to put a recording: inside collect's output. Nothing runs, nothing is deleted.
    stray = _recording(p.root / "data" / "raw" / "train" / "my_rig", n_frames=3, seed=9)
    stray_bytes = _tree(stray)
    refused = p.dvc("repro", "train", check=False)
    assert refused.returncode != 0 and _ran(refused.stdout) == {"guard"}
    assert ("data/raw/train/my_rig/ (8 files, a recorded sequence (source: rig)): inside the output of stage "
            "'collect'") in refused.stderr
    assert "Traceback" not in refused.stderr
    assert _tree(stray) == stray_bytes
    import shutil
    shutil.rmtree(stray)

    # 2. a bad value: compose refuses it, the resolved config and every output stay as they were
    resolved = (p.root / "configs" / "resolved.yaml").read_bytes()
    p.set_overrides(base + ["train.lr=abc"])
    bad = p.dvc("repro", "train", check=False)
    assert bad.returncode != 0 and "train.lr" in bad.stderr and "Traceback" not in bad.stderr
    assert (p.root / "configs" / "resolved.yaml").read_bytes() == resolved

    # 3. Ctrl-C mid-features: the previous features and matches stay, byte for byte
    kept = {f: (p.root / f).read_bytes() for f in ("data/features.parquet", "data/matches.parquet",
                                                   "models/controller.pt", "models/controller.onnx",
                                                   "reports/train.json")}
    p.set_overrides(base + ["features.orb.fast_threshold=19"])
    code, out = _interrupt_when(p, ["repro", "train"], b"features:")
    assert code != 0, out
    assert "expoctl features: interrupted." in out and "Left as before, not replaced: data/features.parquet" in out
    assert {f: (p.root / f).read_bytes() for f in kept} == kept
    status = p.dvc("status", "--with-deps", "train").stdout  # train and the stages it depends on
    assert "features:" in status and "deleted" not in status, status

    # 4. Ctrl-C mid-train (back to the features that are on disk, so only train re-runs)
    p.set_overrides(base + ["train.epochs=500", "train.patience=500"])
    code, out = _interrupt_when(p, ["repro", "train"], b"epoch")
    assert code != 0, out
    assert "expoctl train: interrupted." in out and "Left as before, not replaced: models/controller.pt" in out
    assert "Running stage 'features'" not in out
    assert {f: (p.root / f).read_bytes() for f in kept} == kept
    status = p.dvc("status", "--with-deps", "train").stdout
    assert "train:" in status and "deleted" not in status, status

    # back to the settings the outputs were made with: nothing but compose has to run again
    p.set_overrides(base)
    again = p.dvc("repro", "train")
    assert _ran(again.stdout) == {"guard", "compose"}, again.stdout
    assert {f: (p.root / f).read_bytes() for f in kept} == kept
    assert _tree(rec) == recordings
