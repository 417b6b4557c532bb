"""The random hyperparameter sweep: reproducible draws, applied overrides, and a real 2-trial Hydra multirun."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import mlflow
import pytest
import yaml

from expoctl.errors import ConfigError
from expoctl.host import host_cpu
from tests.support.slurm_cluster import slurm_cluster
from tests.support.synthetic_data import make_synthetic_dataset
from stages.sweep import apply_trial, sample_trial

ROOT = Path(__file__).resolve().parents[2]
SPACE = yaml.safe_load((ROOT / "conf" / "sweep" / "default.yaml").read_text())["sweep"]["space"]


def test_draws_are_reproducible_and_inside_the_space():
    a, b, c = sample_trial(SPACE, 0, 3), sample_trial(SPACE, 0, 3), sample_trial(SPACE, 0, 4)
    assert a == b and a != c
    assert set(a) >= {"train.lr", "train.batch_size", "train.epsilon", "model.dropout", "model.width_multiplier"}
    draws = [sample_trial(SPACE, 1, t) for t in range(20)]
    assert all(1e-5 <= d["train.lr"] <= 3e-3 and 0.2 <= d["train.epsilon"] <= 0.8 for d in draws)
    assert all(d["train.batch_size"] in (16, 32, 64, 128) for d in draws)
    assert len({d["train.batch_size"] for d in draws}) > 1
    with pytest.raises(ConfigError, match="sweep.space.train.lr"):
        sample_trial({"train.lr": {"type": "gaussian"}}, 0, 0)


def test_apply_trial_sets_keys_and_concrete_widths():
    cfg = {"model": {"conv_widths": [30, 60, 120, 240], "fc_widths": [128, 64, 32], "dropout": 0.4},
           "train": {"lr": 1e-4}}
    out, overrides = apply_trial(cfg, {"train.lr": 1e-3, "model.width_multiplier": 0.5})
    assert out["train"]["lr"] == 1e-3 and cfg["train"]["lr"] == 1e-4  # input untouched
    assert out["model"]["conv_widths"] == [15, 30, 60, 120] and out["model"]["fc_widths"] == [64, 32, 16]
    assert overrides == ["train.lr=0.001", "model.conv_widths=[15,30,60,120]", "model.fc_widths=[64,32,16]"]
    with pytest.raises(ConfigError, match="sweep.space.train.nope"):
        apply_trial(cfg, {"train.nope": 1})


def run_sweep(tmp: Path, launcher_args: list[str], env: dict | None = None
              ) -> tuple[dict, mlflow.tracking.MlflowClient, list]:
    """A real 2-trial multirun at fixture scale into `tmp` (own data, sweep dir and SQLite store), `env` added to the
    environment: (best.yaml, client, the trial child runs sorted by trial)."""
    data = make_synthetic_dataset(tmp / "data", n_sequences=4, n_frames=8, hw=(32, 32), seed=0)
    uri = f"sqlite:///{tmp}/mlflow.db"
    cmd = [sys.executable, "-m", "stages.sweep", "scale=fixture", "sweep.trial=range(2)",
           f"hydra.sweep.dir={tmp}/sweep", f"paths.samples={data['samples']}", f"paths.frames={data['frames']}",
           f"paths.images_dir={data['images_dir']}", f"paths.model={tmp}/models/controller.pt",
           f"paths.reports_dir={tmp}/reports", "model.input_size=32", "model.conv_kernels=[3,3,3]",
           "model.pool=2", "train.epochs=2", "train.num_threads=1", *launcher_args]
    env = {**os.environ, "MLFLOW_TRACKING_URI": uri, "PYTHONPATH": str(ROOT), **(env or {})}
    p = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-3000:]
    best = yaml.safe_load((tmp / "sweep" / "best.yaml").read_text())
    client = mlflow.tracking.MlflowClient(uri)
    parent = client.get_run(best["parent_run_id"])
    children = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent.info.run_id}'")
    return best, client, sorted(children, key=lambda r: int(r.data.params["trial"]))


@pytest.fixture(scope="module")
def basic_sweep(tmp_path_factory):
    """The sweep on Hydra's default (basic, in-process) launcher, shared by the tests below."""
    tmp = tmp_path_factory.mktemp("basic-sweep")
    return tmp, *run_sweep(tmp, [])


@pytest.mark.slow
def test_two_trial_sweep_at_fixture_scale(basic_sweep):
    tmp_path, best, client, children = basic_sweep
    assert best["n_trials"] == best["n_trials_finished"] == 2
    parent = client.get_run(best["parent_run_id"])
    assert [r.data.params["trial"] for r in children] == ["0", "1"]
    assert {r.data.tags["host_cpu"] for r in children} == {host_cpu()}  # a trial's throughput names its machine
    objectives = {r.info.run_id: r.data.metrics["objective"] for r in children}
    assert best["best_run_id"] == min(objectives, key=objectives.get)
    assert parent.data.metrics["best_objective"] == pytest.approx(min(objectives.values()))
    assert parent.info.status == "FINISHED"
    assert any(k.startswith("best.train.lr") for k in parent.data.params)
    assert len(client.get_metric_history(children[0].info.run_id, "val_loss")) == 2  # per-epoch series
    # trials write no pipeline outputs
    assert not (tmp_path / "models").exists() and not (tmp_path / "reports").exists()


def assert_same_trials(basic_sweep, tmp_path, best, client, children) -> None:
    """Trial k drew the same values and, trained on one CPU thread, reached bit-identical losses and objective as on
    the basic launcher; only the clocks (samples/s, epoch seconds) differ. The parent run closed with the same best."""
    _, basic_best, _, basic_children = basic_sweep
    assert best["n_trials"] == best["n_trials_finished"] == 2
    assert client.get_run(best["parent_run_id"]).info.status == "FINISHED"

    def results(run):
        return {k: v for k, v in run.data.metrics.items() if not k.endswith(("_per_s", "_seconds"))}

    for a, b in zip(basic_children, children, strict=True):
        assert a.data.params == b.data.params
        assert results(a) == results(b) and "objective" in results(a)
    assert best["best_trial"] == basic_best["best_trial"] and best["overrides"] == basic_best["overrides"]
    assert not (tmp_path / "models").exists() and not (tmp_path / "reports").exists()


def submitit_jobs(tmp_path: Path) -> list[Path]:
    """submitit's folders of the jobs that returned a result (named by job id: a pid locally, `<array>_<task>` on
    SLURM, where the trials go as one job array)."""
    return sorted(d for d in (tmp_path / "sweep" / ".submitit").iterdir() if any(d.glob(f"{d.name}_*_result.pkl")))


@pytest.mark.slow
def test_sweep_through_submitit_matches_the_basic_launcher(basic_sweep, tmp_path):
    """hydra/launcher=submitit_local: each trial is pickled by submitit and runs in its own process."""
    run = run_sweep(tmp_path, ["hydra/launcher=submitit_local", "hydra.launcher.timeout_min=10",
                               "hydra.launcher.cpus_per_task=1"])
    assert len(submitit_jobs(tmp_path)) == 2  # local job ids are the jobs' pids
    assert_same_trials(basic_sweep, tmp_path, *run)


@pytest.mark.slow
def test_sweep_on_a_real_slurm_cluster_matches_the_basic_launcher(basic_sweep, tmp_path):
    """hydra/launcher=submitit_slurm on a private single-node SLURM 22.05 cluster (slurmctld + slurmd on 127.0.0.1,
    tests/support/slurm_cluster.py): each trial an sbatch job, as on a real cluster."""
    with slurm_cluster() as env:
        run = run_sweep(tmp_path, ["hydra/launcher=submitit_slurm", "hydra.launcher.partition=debug",
                                   "hydra.launcher.timeout_min=10", "hydra.launcher.cpus_per_task=1"], env)
        jobs = submitit_jobs(tmp_path)
        assert len(jobs) == 2
        # SLURM ran them: its controller still knows both array tasks, completed (a task's result file is written
        # before its python process, and so the task, ends: wait for that)
        for job in jobs:
            deadline = time.monotonic() + 60
            while True:
                p = subprocess.run(["scontrol", "-o", "show", "job", job.name], capture_output=True, text=True,
                                   env={**os.environ, **env})
                state = re.search(r"JobState=(\S+)", p.stdout)
                if state is None or state.group(1) not in ("RUNNING", "COMPLETING") or time.monotonic() > deadline:
                    break
                time.sleep(0.5)
            assert state is not None and state.group(1) == "COMPLETED", p.stdout + p.stderr
    assert_same_trials(basic_sweep, tmp_path, *run)
