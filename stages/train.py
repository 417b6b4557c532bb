"""train stage: samples + image store → models/controller.pt, models/controller.onnx, reports/train.json.

Reads only `seed`, `model`, `train`, `sensor` (the camera response, for `train.exposure_shift_probability`) and its
paths from configs/resolved.yaml. Per-epoch metrics go to the stage's
MLflow run; the final metrics put the validation error (gain in dB, exposure in EV) next to the constant-predictor
baseline; the model is logged with mlflow.pytorch.log_model.

Scale-out: the same command runs data-parallel under torchrun, e.g.
    torchrun --standalone --nproc_per_node 2 -m stages.train
(gloo backend on CPU; `train.batch_size` stays the global batch). Only rank 0 opens the MLflow run and writes files.
Give each process its share of the cores with `train.num_threads` (cores / nproc_per_node).

Device: `train.device` (auto | cpu | cuda; auto = cuda when torch.cuda.is_available()). On GPUs, one process per GPU
(`--nproc_per_node <GPUs per node>`): the nccl backend, and each process trains on `cuda:<LOCAL_RANK>`; on the CPU,
gloo as before. `train.device: cuda` on a machine without CUDA stops before any data load (ConfigError naming
`train.device`). The checkpoint and the ONNX export are written from CPU tensors on any device. The device is not part
of the result, but `train.device` sits in the `train` group, which is all in the train stage's DVC params
(stages/keys.py): changing it (e.g. auto → cuda) re-runs train; `auto` resolves per machine without a re-run. On a SLURM cluster,
one task per node, e.g. 2 nodes × 4 processes:
    srun --nodes 2 --ntasks-per-node 1 --cpus-per-task 32 torchrun --nnodes 2 --nproc_per_node 4 \
        --rdzv_backend c10d --rdzv_endpoint "$(scontrol show hostnames $SLURM_NODELIST | head -1):29500" -m stages.train
(the project directory and data on a shared filesystem; MLFLOW_TRACKING_URI pointing at a tracking server).
Hyperparameter sweeps go through Hydra's submitit launcher instead: see stages/sweep.py.
"""

from __future__ import annotations

import logging
import os
import sys
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist

from expoctl.net.dataset import load_sample_sets_from_files
from expoctl.errors import InputError
from expoctl.io import write_json
from expoctl.net.model import ModelConfig
from expoctl.net.train import TrainConfig, fit, predict, resolve_device
from expoctl.net.checkpoint import checkpoint_dict, export_onnx

log = logging.getLogger("expoctl.train")


def _path(p) -> Path:
    from stages.project import PROJECT_ROOT

    p = Path(p)
    return p if p.is_absolute() else PROJECT_ROOT / p


def configs(cfg: dict) -> tuple[ModelConfig, TrainConfig, int]:
    """The stage's typed configs, built once before any work; every problem of the three at once (ConfigError)."""
    from expoctl.config_reader import Problems, Section, read_seed

    problems = Problems()
    seed = read_seed(Section(cfg, "", problems))
    model_cfg = ModelConfig.from_dict(cfg.get("model"), "model", problems)
    train_cfg = TrainConfig.from_dict(cfg.get("train"), "train", problems)
    problems.raise_if_any()
    return model_cfg, train_cfg, seed


def camera_response(cfg: dict, train_cfg: TrainConfig):
    """The camera response the stored images were encoded with (the `sensor` block), when synthetic over-exposure
    needs it; None otherwise."""
    from expoctl.camera.sensor import SensorConfig
    from expoctl.errors import ConfigError

    if train_cfg.exposure_shift_probability == 0:
        return None
    if not isinstance(cfg.get("sensor"), dict):
        raise ConfigError("sensor", "missing: train.exposure_shift_probability > 0 needs the camera response")
    return SensorConfig.from_dict(cfg["sensor"], "sensor").response()


def training_device(train_cfg: TrainConfig) -> torch.device:
    """`train.device` for this process: under torchrun, CUDA device LOCAL_RANK (one GPU per process)."""
    local_rank = os.environ.get("LOCAL_RANK")
    return resolve_device(train_cfg.device, int(local_rank) if local_rank is not None else None)


def _backend() -> str:
    """The process group's backend under torchrun: nccl when this process will train on CUDA, else gloo. A config
    that does not read falls back to gloo: the stage reports its problems itself."""
    from stages.project import load_resolved

    if not torch.cuda.is_available():
        return "gloo"
    try:
        device = TrainConfig.from_dict(load_resolved().get("train")).device
    except InputError:
        return "gloo"
    return "gloo" if device == "cpu" else "nccl"


def train_from_config(cfg: dict, on_epoch=None, sets=None):
    """Load data (unless `sets` given) and fit; shared by this stage and the sweep. Returns (result, sets, configs)."""
    model_cfg, train_cfg, seed = configs(cfg)
    response = camera_response(cfg, train_cfg)  # before the data load: a config problem costs nothing
    device = training_device(train_cfg)  # likewise: cuda without CUDA stops here
    log.info("training on %s", device)
    paths = cfg["paths"]
    if sets is None:
        sets = load_sample_sets_from_files(_path(paths["samples"]), _path(paths["frames"]), _path(paths["images_dir"]),
                                           model_cfg.input_size, exposure_scale=model_cfg.exposure_scale)
    for split in ("train", "validation"):
        if split not in sets:
            raise InputError(f"{paths['samples']}: no samples with split '{split}'")
    result = fit(model_cfg, train_cfg, sets["train"], sets["validation"], seed, on_epoch=on_epoch, log=log.info,
                 response=response, device=device)
    return result, sets, (model_cfg, train_cfg, seed)


def _keep_previous_model(cfg: dict, tracker) -> None:
    """train_iter<N> with iteration N disabled: its model is the previous iteration's (copied, so later stages have
    one path to read)."""
    import shutil

    from expoctl.io import atomic_path

    n = cfg["iteration"]
    src_model = _path(cfg["paths_prev"]["model"])
    if not src_model.is_file():
        raise InputError(f"{src_model}: the iteration-{n - 1} model is missing (run its train stage)")
    pairs = [(src_model, _path(cfg["paths"]["model"])),
             (src_model.with_suffix(".onnx"), _path(cfg["paths"]["model"]).with_suffix(".onnx")),
             (_path(cfg["paths_prev"]["reports_dir"]) / "train.json", _path(cfg["paths"]["reports_dir"]) / "train.json")]
    for src, dst in pairs:
        with atomic_path(dst) as tmp:
            shutil.copyfile(src, tmp)
    tracker.log_metrics({f"iteration{n}_enabled": 0.0})
    log.info("iteration %d disabled: keeping the iteration-%d model as %s", n, n - 1, pairs[0][1])


def run(cfg: dict, tracker):
    """The stage (rank 0 writes and logs); returns the TrainResult (None when this iteration is disabled)."""
    if cfg.get("iteration", 1) > 1 and not cfg["iteration_block"].get("enabled", True):
        _keep_previous_model(cfg, tracker)
        return None
    rank = dist.get_rank() if dist.is_available() and dist.is_initialized() else 0
    result, sets, (model_cfg, train_cfg, seed) = train_from_config(
        cfg, on_epoch=lambda epoch, m: tracker.log_metrics(m, step=epoch))
    if rank == 0:
        _write_outputs(cfg, tracker, result, sets, model_cfg, train_cfg, seed)
    if dist.is_available() and dist.is_initialized():
        dist.barrier()
    return result


def _write_outputs(cfg, tracker, result, sets, model_cfg, train_cfg, seed) -> None:
    from expoctl.io import atomic_path

    m = result.metrics
    log.info("validation: gain %.2f dB (constant %.2f), exposure %.3f EV (constant %.3f), loss %.4f vs %.4f",
             m["val_gain_mae_db"], m["baseline_val_gain_mae_db"], m["val_exposure_mae_ev"],
             m["baseline_val_exposure_mae_ev"], m["val_loss"], m["baseline_val_loss"])
    if not m["beats_baseline"]:
        log.warning("the model does NOT beat the constant predictor on validation loss")
    model_path = _path(cfg["paths"]["model"])
    onnx_path = model_path.with_suffix(".onnx")
    report_path = _path(cfg["paths"]["reports_dir"]) / "train.json"
    ckpt = checkpoint_dict(result, model_cfg, train_cfg, sets["train"].store_hw, seed)
    ckpt["history"] = result.history  # per-epoch metrics (also in MLflow); train.json stays flat for `dvc metrics`
    with atomic_path(model_path, suffix=".pt") as tmp:
        torch.save(ckpt, tmp)
    export_onnx(result.model, onnx_path, train_cfg.onnx_exporter)
    onnx_err = _onnx_agreement(onnx_path, sets["validation"], result.model)
    if not onnx_err < 1e-4:
        raise RuntimeError(f"{onnx_path}: ONNX outputs differ from torch by {onnx_err:.2e} (> 1e-4)")
    m = {**m, "onnx_max_abs_diff": onnx_err}
    write_json(m, report_path)
    # "final." keeps these apart from the per-epoch series of the same names
    tracker.log_metrics({f"final.{k}": float(v) for k, v in m.items()})
    for p in (model_path, onnx_path, report_path):
        tracker.log_artifact(p)
    _log_model(result.model, model_cfg, train_cfg.mlflow_model_format)


def _onnx_agreement(onnx_path: Path, data, model, n: int = 64) -> float:
    """Max |ONNX − torch| on up to n real validation samples."""
    import onnxruntime as ort

    rows = np.arange(min(n, len(data)))
    x, _ = data.batch(rows)
    sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    return float(np.abs(sess.run(None, {"input": x.numpy()})[0] - predict(model, data, rows=rows)).max())


def _log_model(model, model_cfg, serialization_format: str) -> None:
    """mlflow.pytorch.log_model on the active run (skipped when there is none, e.g. a test's fake tracker)."""
    import mlflow

    if mlflow.active_run() is None:
        return
    import mlflow.pytorch

    h, w = model_cfg.input_size
    example = np.zeros((1, 15, h, w), np.float32)
    # explicit pip requirements: inferring them imports the whole environment (slow)
    mlflow.pytorch.log_model(model, name="model", input_example=example,
                             pip_requirements=[f"torch=={torch.__version__.split('+')[0]}", f"numpy=={np.__version__}"],
                             serialization_format=serialization_format)


def _worker_main() -> None:
    """Ranks > 0 under torchrun: same work, no MLflow run, no outputs."""

    class _NoTracker:
        def log_params(self, *a, **k): ...
        def log_metrics(self, *a, **k): ...
        def log_artifact(self, *a, **k): ...

    from stages.project import load_resolved

    try:
        run(load_resolved(), _NoTracker())
    except InputError as exc:
        print(f"expoctl train (rank {dist.get_rank()}): error: {exc}", file=sys.stderr)
        sys.exit(2)


def main() -> None:
    from stages.common import stage_main

    distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if distributed:
        backend = _backend()
        if backend == "nccl":
            torch.cuda.set_device(int(os.environ.get("LOCAL_RANK", "0")))
        dist.init_process_group(backend)
    try:
        if not distributed or dist.get_rank() == 0:
            stage_main("train", run)
        else:
            _worker_main()
    finally:
        if distributed:
            dist.destroy_process_group()


if __name__ == "__main__":
    main()
