"""A throw-away copy of the project (tracked + new files, no data) where `dvc repro` can run for real."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def _project_files() -> list[str]:
    out = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=PROJECT_ROOT, capture_output=True,
                         text=True, check=True).stdout.split("\n")
    return [f for f in out if f and (PROJECT_ROOT / f).is_file()]


class ProjectCopy:
    def __init__(self, root: Path, env: dict[str, str]):
        self.root = root
        self.env = env

    def run(self, *cmd: str, check: bool = True) -> subprocess.CompletedProcess:
        p = subprocess.run(list(cmd), cwd=self.root, env=self.env, capture_output=True, text=True)
        if check and p.returncode != 0:
            raise AssertionError(f"{' '.join(cmd)} failed ({p.returncode}):\n{p.stdout[-4000:]}\n{p.stderr[-4000:]}")
        return p

    def dvc(self, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        return self.run(sys.executable, "-m", "dvc", *args, check=check)

    def set_overrides(self, overrides: list[str]) -> None:
        import yaml
        (self.root / "params.yaml").write_text(yaml.safe_dump({"overrides": overrides}))

    def stage_runs(self, children: bool = False) -> dict[str, int]:
        """Number of MLflow stage runs (or, with `children`, of their nested child runs) per `stage` tag in this
        copy's own store."""
        import mlflow
        client = mlflow.MlflowClient(tracking_uri=self.env["MLFLOW_TRACKING_URI"])
        exp = client.get_experiment_by_name("expoctl")
        counts: dict[str, int] = {}
        for r in client.search_runs([exp.experiment_id], max_results=5000):
            if ("mlflow.parentRunId" in r.data.tags) == children:
                counts[r.data.tags["stage"]] = counts.get(r.data.tags["stage"], 0) + 1
        return counts


@pytest.fixture
def project_copy(tmp_path: Path) -> ProjectCopy:
    root = tmp_path / "project"
    for f in _project_files():
        dst = root / f
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(PROJECT_ROOT / f, dst)
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["MLFLOW_TRACKING_URI"] = f"sqlite:///{tmp_path / 'mlflow.db'}"
    # expoctl itself comes from the editable install, i.e. this checkout's src/, which the copy's files equal: its
    # numba kernels are compiled and cached there once, where a copy's own src/ would compile them all again (minutes)
    env["PYTHONPATH"] = str(root)
    env.setdefault("GIT_AUTHOR_NAME", "test")
    env.setdefault("GIT_AUTHOR_EMAIL", "test@example.com")
    env.setdefault("GIT_COMMITTER_NAME", "test")
    env.setdefault("GIT_COMMITTER_EMAIL", "test@example.com")
    copy = ProjectCopy(root, env)
    copy.run("git", "init", "-q")
    copy.set_overrides(["scale=fixture"])
    copy.run("git", "add", "-A")
    copy.run("git", "commit", "-qm", "fixture copy")
    return copy
