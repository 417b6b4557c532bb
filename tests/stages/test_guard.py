"""The guard stage, in a tiny real DVC project: a file a user put inside a stage's output directory survives
`dvc repro`, which stops before any stage runs; without foreign files the guard changes nothing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from synthetic_raw import write_synthetic_sequence

from stages.guard import GUARD_STAMP, STAMP_TEXT, foreign_files, main

PROJECT_ROOT = Path(__file__).resolve().parents[2]
GUARD_CMD = "python -c 'import sys, pathlib; from stages.guard import main; sys.exit(main(pathlib.Path.cwd()))'"


def _dvc_project(root: Path) -> dict:
    """guard → make (writes out/a.txt and out/b/c.txt into the directory output `out`, replaced whole)."""
    root.mkdir()
    (root / "dvc.yaml").write_text(yaml.safe_dump({"stages": {
        "guard": {"cmd": GUARD_CMD, "always_changed": True,
                  "outs": [{str(GUARD_STAMP): {"cache": False, "persist": True}}]},
        "make": {"cmd": "rm -rf out && mkdir -p out/b && cat in.txt > out/a.txt && echo c > out/b/c.txt",
                 "deps": [str(GUARD_STAMP), "in.txt"], "outs": ["out"]},
    }}, sort_keys=False))
    (root / "in.txt").write_text("1\n")
    env = dict(os.environ, PYTHONPATH=str(PROJECT_ROOT),
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    for cmd in (["git", "init", "-q"], [sys.executable, "-m", "dvc", "init", "-q"]):
        subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True)
    return env


def _dvc(root: Path, env: dict, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dvc", *args], cwd=root, env=env, capture_output=True, text=True)


@pytest.mark.slow
def test_a_file_put_into_an_output_survives_repro(tmp_path):
    root = tmp_path / "p"
    env = _dvc_project(root)
    first = _dvc(root, env, "repro")
    assert first.returncode == 0, first.stdout + first.stderr
    assert (root / GUARD_STAMP).read_text() == STAMP_TEXT
    # a user's recording copied into the output, then the input changes: `make` would replace `out` whole
    mine = write_synthetic_sequence(root / "out" / "train" / "rig_000", n_frames=2)
    (mine / "sequence.yaml").write_text((mine / "sequence.yaml").read_text().replace("source: sim", "source: rig"))
    before = {p: p.read_bytes() for p in mine.rglob("*") if p.is_file()}
    (root / "in.txt").write_text("2\n")
    second = _dvc(root, env, "repro")
    assert second.returncode != 0
    err = second.stderr + second.stdout
    assert "out/train/rig_000/ (6 files, a recorded sequence (source: rig)): inside the output of stage 'make'" in err
    assert "data/recordings/<split>/<sequence>/" in err and "Traceback" not in err
    assert "Running stage 'make'" not in err
    assert {p: p.read_bytes() for p in mine.rglob("*") if p.is_file()} == before
    assert (root / "out" / "a.txt").read_text() == "1\n"  # the stage did not run
    # moved out of the way, the pipeline runs again; the guard leaves its stamp as it was
    stamp_mtime = (root / GUARD_STAMP).stat().st_mtime_ns
    (root / "out" / "train").rename(tmp_path / "moved")
    third = _dvc(root, env, "repro")
    assert third.returncode == 0, third.stdout + third.stderr
    assert (root / "out" / "a.txt").read_text() == "2\n"
    assert (root / GUARD_STAMP).stat().st_mtime_ns == stamp_mtime
    # a second repro runs only the guard (always changed), nothing else
    fourth = _dvc(root, env, "repro")
    assert "Stage 'make' didn't change, skipping" in fourth.stdout


def test_unrun_raw_output_simulated_sequences_pass_recordings_do_not(tmp_path):
    """Before collect ever ran (no dvc.lock), data/raw may hold only the simulator's sequences (`source: sim`, e.g.
    from `python -m stages.collect` by hand); a real recording there is named, every file counted."""
    root = tmp_path / "p"
    root.mkdir()
    (root / "dvc.yaml").write_text(yaml.safe_dump({"stages": {"collect": {"cmd": "true", "outs": ["data/raw"]}}}))
    write_synthetic_sequence(root / "data" / "raw" / "train" / "sim_000", n_frames=2)
    assert foreign_files(root) == {}
    rec = write_synthetic_sequence(root / "data" / "raw" / "validation" / "rig_001", n_frames=3)
    (rec / "sequence.yaml").write_text((rec / "sequence.yaml").read_text().replace("source: sim", "source: rig"))
    assert foreign_files(root) == {"data/raw": ("collect", {"validation/rig_001/": 8})}
    assert main(root) == 2 and not (root / GUARD_STAMP).exists()


def test_no_outputs_yet_writes_the_stamp(tmp_path):
    root = tmp_path / "p"
    root.mkdir()
    (root / "dvc.yaml").write_text(yaml.safe_dump({"stages": {"collect": {"cmd": "true", "outs": ["data/raw"]}}}))
    assert main(root) == 0
    assert (root / GUARD_STAMP).read_text() == STAMP_TEXT
