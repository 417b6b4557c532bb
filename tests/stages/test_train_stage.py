"""The train stage: outputs, MLflow logging (temporary SQLite store), and data-parallel runs under torchrun."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import mlflow
import pytest
import torch
import yaml

from expoctl.errors import ConfigError
from tests.support.synthetic_data import make_synthetic_dataset
from expoctl.net.checkpoint import load_checkpoint
from stages import train as stage

ROOT = Path(__file__).resolve().parents[2]


def make_cfg(tmp: Path, **train) -> dict:
    p = make_synthetic_dataset(tmp / "data", n_sequences=4, n_frames=10, hw=(32, 32), seed=0)
    return {
        "seed": 0,
        "numerics": {"mode": "pinned"},  # conf/numerics/default.yaml
        "sensor": {},  # the defaults' response (read only with train.exposure_shift_probability > 0)
        "model": {"input_size": 32, "conv_widths": [8, 8, 16, 16], "conv_kernels": [3, 3, 3], "pool": 2,
                  "fc_widths": [16, 8, 8], "dropout": 0.1},
        "train": {"lr": 3e-3, "batch_size": 32, "epochs": 3, "patience": 5, "num_threads": 1,
                  "mlflow_model_format": "pickle", **train},
        "paths": {"samples": str(p["samples"]), "frames": str(p["frames"]), "images_dir": str(p["images_dir"]),
                  "model": str(tmp / "models" / "controller.pt"), "reports_dir": str(tmp / "reports")},
    }


@pytest.fixture()
def mlflow_store(tmp_path, monkeypatch):
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path}/mlflow.db")
    yield f"sqlite:///{tmp_path}/mlflow.db"
    mlflow.set_tracking_uri(None)


def test_stage_writes_model_onnx_report_and_logs_to_mlflow(tmp_path, mlflow_store):
    from stages.tracking import tracked_run

    cfg = make_cfg(tmp_path)
    with tracked_run("train", cfg) as tracker:
        stage.run(cfg, tracker)
        run_id = tracker.run_id
    model, ckpt = load_checkpoint(tmp_path / "models" / "controller.pt")
    assert ckpt["input_hw"] == [32, 32] and ckpt["store_hw"] == [32, 32]
    assert (tmp_path / "models" / "controller.onnx").exists()
    report = json.loads((tmp_path / "reports" / "train.json").read_text())
    assert report["onnx_max_abs_diff"] < 1e-4
    assert len(ckpt["history"]) == report["epochs_run"] == 3
    assert report["val_loss"] == pytest.approx(min(h["val_loss"] for h in ckpt["history"]))
    client = mlflow.tracking.MlflowClient(mlflow_store)
    hist = client.get_metric_history(run_id, "val_loss")
    assert [h.step for h in hist] == [0, 1, 2]
    data = client.get_run(run_id).data
    assert "final.baseline_val_exposure_mae_ev" in data.metrics and "final.improvement_gain_db" in data.metrics
    assert data.metrics["final.val_loss"] == pytest.approx(report["val_loss"])
    # the closed-loop amplification probe rides along (expoctl.net.follow), in the report and in MLflow
    assert math.isfinite(report["val_follow"])
    assert data.metrics["final.val_follow"] == pytest.approx(report["val_follow"])
    exp = client.get_run(run_id).info.experiment_id
    models = mlflow.search_logged_models(experiment_ids=[exp], filter_string=f"source_run_id = '{run_id}'",
                                         output_format="list")
    assert [m.name for m in models] == ["model"]


def test_bad_config_fails_before_work(tmp_path):
    cfg = make_cfg(tmp_path, lr=-1.0)
    with pytest.raises(ConfigError, match="train.lr"):
        stage.run(cfg, None)
    assert not (tmp_path / "models").exists()


def test_exposure_shift_reads_the_sensor_response(tmp_path):
    cfg = make_cfg(tmp_path, exposure_shift_probability=0.25)
    del cfg["sensor"]
    with pytest.raises(ConfigError, match="sensor"):  # no sensor block: named, before any work
        stage.run(cfg, None)
    assert not (tmp_path / "models").exists()
    cfg["sensor"] = {"response_curve": "cubic"}
    with pytest.raises(ConfigError, match="sensor.response_curve"):
        stage.run(cfg, None)
    cfg["sensor"] = {"response_curve": "gamma", "response_gamma": 1.8}
    response = stage.camera_response(cfg, stage.configs(cfg)[1])
    assert response.curve == "gamma" and response.gamma_rgb.tolist() == [1.8] * 3
    cfg["train"]["exposure_shift_probability"] = 0.0  # off: the sensor block is not read
    del cfg["sensor"]
    assert stage.camera_response(cfg, stage.configs(cfg)[1]) is None


WORKER = textwrap.dedent("""
    import json, sys, torch, torch.distributed as dist
    from stages import train as stage
    class T:
        def log_params(self, *a, **k): pass
        def log_metrics(self, *a, **k): pass
        def log_artifact(self, *a, **k): pass
    dist.init_process_group("gloo")
    cfg = json.load(open(sys.argv[1]))
    result = stage.run(cfg, T())
    torch.save(result.model.state_dict(), sys.argv[2] + f".rank{dist.get_rank()}")
    dist.destroy_process_group()
""")


@pytest.mark.slow
def test_torchrun_two_cpu_processes(tmp_path):
    cfg = make_cfg(tmp_path, epochs=2)
    (tmp_path / "cfg.json").write_text(json.dumps(cfg))
    (tmp_path / "worker.py").write_text(WORKER)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    p = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                        str(tmp_path / "worker.py"), str(tmp_path / "cfg.json"), str(tmp_path / "state")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    s0, s1 = (torch.load(tmp_path / f"state.rank{r}") for r in (0, 1))
    ckpt_model, ckpt = load_checkpoint(tmp_path / "models" / "controller.pt")  # written by rank 0 only
    assert ckpt["metrics"]["n_processes"] == 2
    for k in s0:  # DDP keeps the replicas identical (BN buffers broadcast from rank 0)
        assert torch.equal(s0[k], s1[k]), k
        assert torch.equal(s0[k], ckpt_model.state_dict()[k]), k


@pytest.mark.slow
def test_stage_entry_point_unchanged_under_torchrun(tmp_path):
    """`torchrun --nproc_per_node 2 -m stages.train` in a throw-away project: rank 0 logs one run and writes."""
    import shutil

    proj = tmp_path / "proj"
    shutil.copytree(ROOT / "stages", proj / "stages", ignore=shutil.ignore_patterns("__pycache__"))
    cfg = make_cfg(tmp_path, epochs=2)
    (proj / "configs").mkdir()
    (proj / "configs" / "resolved.yaml").write_text(yaml.safe_dump(cfg))
    env = {**os.environ, "PYTHONPATH": str(proj), "OMP_NUM_THREADS": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)  # the embedded store of the throw-away project
    p = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                        "-m", "stages.train"], cwd=proj, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    _, ckpt = load_checkpoint(tmp_path / "models" / "controller.pt")
    assert ckpt["metrics"]["n_processes"] == 2
    client = mlflow.tracking.MlflowClient(f"sqlite:///{proj / 'mlflow.db'}")
    exp = client.get_experiment_by_name("expoctl")
    runs = client.search_runs([exp.experiment_id])
    assert [r.data.tags["stage"] for r in runs] == ["train"]  # one run, from rank 0 only
    assert runs[0].data.metrics["final.n_processes"] == 2


# ---------------------------------------------------------------------------------------------------- train.device

class _Tracker:
    def log_params(self, *a, **k): ...
    def log_metrics(self, *a, **k): ...
    def log_artifact(self, *a, **k): ...


def test_bad_device_is_named_before_work(tmp_path):
    cfg = make_cfg(tmp_path, device="gpu")
    with pytest.raises(ConfigError, match="train.device"):
        stage.run(cfg, None)
    assert not (tmp_path / "models").exists()


def test_cuda_without_cuda_fails_before_the_data_load(tmp_path, monkeypatch):
    cfg = make_cfg(tmp_path, device="cuda")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)

    def no_load(*a, **k):
        raise AssertionError("the data were loaded before the device was checked")

    monkeypatch.setattr(stage, "load_sample_sets_from_files", no_load)
    with pytest.raises(ConfigError, match="train.device") as exc:
        stage.run(cfg, None)
    assert "cuda" in str(exc.value)
    assert not (tmp_path / "models").exists()


def test_device_follows_local_rank_under_torchrun(monkeypatch):
    from expoctl.net.train import TrainConfig

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 4)
    monkeypatch.setenv("LOCAL_RANK", "2")
    assert stage.training_device(TrainConfig(device="cuda")) == torch.device("cuda", 2)
    assert stage.training_device(TrainConfig(device="auto")) == torch.device("cuda", 2)
    assert stage.training_device(TrainConfig(device="cpu")) == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert stage.training_device(TrainConfig(device="auto")) == torch.device("cpu")


@pytest.mark.parametrize("cuda, device, backend", [(False, "auto", "gloo"), (False, "cuda", "gloo"),
                                                   (True, "auto", "nccl"), (True, "cuda", "nccl"),
                                                   (True, "cpu", "gloo"), (True, "gpu", "gloo")])
def test_torchrun_backend_nccl_on_cuda_gloo_on_cpu(monkeypatch, cuda, device, backend):
    """main() under torchrun (WORLD_SIZE > 1): nccl and cuda:<LOCAL_RANK> when the process trains on CUDA, gloo
    otherwise (a bad or unavailable device falls back to gloo: the stage then reports it). The process group and
    the stage are recorded, not run."""
    import stages.common
    import stages.project

    calls = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: cuda)
    monkeypatch.setattr(torch.cuda, "set_device", lambda i: calls.append(("set_device", i)))
    monkeypatch.setattr(stages.project, "load_resolved", lambda: {"train": {"device": device}})
    monkeypatch.setattr(stage.dist, "init_process_group", lambda b: calls.append(("init", b)))
    monkeypatch.setattr(stage.dist, "get_rank", lambda: 0)
    monkeypatch.setattr(stage.dist, "destroy_process_group", lambda: calls.append(("destroy",)))
    monkeypatch.setattr(stages.common, "stage_main", lambda name, run: calls.append(("stage", name)))
    monkeypatch.setenv("WORLD_SIZE", "2")
    monkeypatch.setenv("LOCAL_RANK", "1")
    stage.main()
    expect = [("set_device", 1)] if backend == "nccl" else []
    assert calls == expect + [("init", backend), ("stage", "train"), ("destroy",)]


def test_cpu_run_is_identical_to_the_default(tmp_path):
    """train.device: cpu writes the same weights as a config without the key (auto, on this CPU machine); the
    checkpoint holds CPU tensors."""
    cfg = make_cfg(tmp_path, device="cpu")
    stage.run(cfg, _Tracker())
    _, ckpt = load_checkpoint(tmp_path / "models" / "controller.pt")
    default = {**cfg, "train": {k: v for k, v in cfg["train"].items() if k != "device"}}
    result, _, _ = stage.train_from_config(default)
    assert ckpt["train_config"]["device"] == "cpu"
    assert {v.device.type for v in ckpt["state_dict"].values()} == {"cpu"}
    for k, v in result.model.state_dict().items():
        assert torch.equal(ckpt["state_dict"][k], v), k
