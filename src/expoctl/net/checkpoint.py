"""The controller checkpoint (models/controller.pt: weights, architecture, preprocessing sizes) and its ONNX export.

`checkpoint_dict` builds it from a training result (`expoctl.net.train`), `load_checkpoint` reads it back and checks
it (the deployed controller, `expoctl.controllers.learned`), `export_onnx` writes the network as ONNX. Every stage that
reads a network calls `check_checkpoint` first, before any other work, so a truncated or mismatched file stops the
stage at once with its path and the problem (`onnx_session` checks the .onnx beside it).
"""

from __future__ import annotations

import copy
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from expoctl.errors import ConfigError, InputError
from expoctl.net.model import ExposureNet, ModelConfig
from expoctl.net.preprocess import CHANNEL_NAMES

if TYPE_CHECKING:
    from expoctl.net.train import TrainConfig, TrainResult

CHECKPOINT_FORMAT = "expoctl-controller-v1"


def checkpoint_dict(result: TrainResult, model_cfg: ModelConfig, cfg: TrainConfig, store_hw, seed: int) -> dict:
    """Everything the deployed controller needs: weights, architecture, and the preprocessing sizes."""
    return {
        "format": CHECKPOINT_FORMAT,
        "model_config": model_cfg.to_dict(),
        "state_dict": {k: v.detach().clone() for k, v in result.model.state_dict().items()},
        "store_hw": [int(v) for v in store_hw],
        "input_hw": [int(v) for v in model_cfg.input_size],
        "channel_names": list(CHANNEL_NAMES),
        "train_config": {k: v for k, v in asdict(cfg).items()},
        "seed": int(seed),
        "metrics": {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in result.metrics.items()},
    }


def load_checkpoint(path) -> tuple[ExposureNet, dict]:
    """Load models/controller.pt → (model in eval mode, checkpoint metadata), every check on the way.

    Any problem is an `InputError` naming the file and what is wrong: missing, empty, truncated or not a PyTorch file,
    not an expoctl controller checkpoint, a bad `model_config`, a `state_dict` that does not match the architecture
    in `model_config` (every missing / unexpected key and every shape mismatch), `input_hw` / `store_hw` that are not
    [height, width] positive integers or an `input_hw` other than the network's input size."""
    ckpt = _read_checkpoint(path)
    cfg = _model_config(path, ckpt)
    model = ExposureNet(cfg)
    _check_state_dict(path, ckpt["state_dict"], model)
    _check_sizes(path, ckpt, cfg)
    try:
        model.load_state_dict(ckpt["state_dict"], strict=True)
    except Exception as exc:  # noqa: BLE001 — shapes and keys were checked; anything else is still the file's fault
        raise InputError(f"{path}: state_dict does not load into the model_config architecture "
                         f"({_first_line(exc)})") from None
    model.eval()
    return model, ckpt


def check_checkpoint(path, onnx: bool = False) -> dict:
    """The check a stage runs on a network it reads, before any other work: `load_checkpoint`'s checks and, with
    `onnx`, that the sibling .onnx exists, loads in onnxruntime and takes the checkpoint's (batch, 15, h, w) input.
    Returns the checkpoint metadata; raises `InputError` naming the file and the problem."""
    _, ckpt = load_checkpoint(path)
    if onnx:
        onnx_session(Path(path).with_suffix(".onnx"), ckpt["input_hw"])
    return ckpt


def onnx_session(onnx_path, input_hw, num_threads: int | None = None):
    """An onnxruntime session of the exported network at `onnx_path`, checked: it exists, loads, has one input named
    "input" of shape (batch, 15, h, w) with (h, w) = `input_hw`, and one (batch, 2) output; `InputError` otherwise."""
    import onnxruntime as ort

    onnx_path = Path(onnx_path)
    if not onnx_path.is_file():
        raise InputError(f"{onnx_path}: ONNX export missing (it is written beside the checkpoint by the train stage)")
    opts = ort.SessionOptions()
    if num_threads:
        opts.intra_op_num_threads = int(num_threads)
        opts.inter_op_num_threads = 1
    try:
        session = ort.InferenceSession(str(onnx_path), opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001 — onnxruntime raises its own exception types
        size = onnx_path.stat().st_size
        raise InputError(f"{onnx_path}: not loadable by onnxruntime: truncated or not an ONNX model ({size} bytes; "
                         f"{_first_line(exc)})") from None
    inputs, outputs = session.get_inputs(), session.get_outputs()
    h, w = (int(v) for v in input_hw)
    expected = [len(CHANNEL_NAMES), h, w]
    if len(inputs) != 1 or inputs[0].name != "input":
        raise InputError(f"{onnx_path}: ONNX inputs {[i.name for i in inputs]}, expected one named 'input'")
    shape = list(inputs[0].shape)
    if len(shape) != 4 or [d if isinstance(d, int) else None for d in shape[1:]] != expected:
        raise InputError(f"{onnx_path}: ONNX input has shape {shape}, expected [batch, {', '.join(map(str, expected))}]"
                         " (the checkpoint's input_hw)")
    if len(outputs) != 1 or len(outputs[0].shape) != 2 or outputs[0].shape[1] != 2:
        raise InputError(f"{onnx_path}: ONNX outputs {[(o.name, o.shape) for o in outputs]}, expected one of shape "
                         "[batch, 2]")
    return session


def _read_checkpoint(path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: model checkpoint not found")
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 — torch raises RuntimeError, OSError, UnpicklingError, …
        raise InputError(f"{path}: {_why_unreadable(path, exc)}") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        found = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        raise InputError(f"{path}: not an expoctl controller checkpoint (format {CHECKPOINT_FORMAT} expected, "
                         f"found {found!r})")
    missing = [k for k in ("model_config", "state_dict", "store_hw", "input_hw") if k not in ckpt]
    if missing:
        raise InputError(f"{path}: checkpoint lacks key(s) {missing}")
    if not isinstance(ckpt["state_dict"], dict) or not all(isinstance(v, torch.Tensor)
                                                          for v in ckpt["state_dict"].values()):
        raise InputError(f"{path}: state_dict is not a mapping of tensors")
    return ckpt


def _why_unreadable(path: Path, exc: Exception) -> str:
    """What is wrong with a file torch.load could not read, in words: torch's own message for a truncated file is
    `[Errno 22] Invalid argument`."""
    import zipfile

    size = path.stat().st_size
    if size == 0:
        return "empty file, not a PyTorch checkpoint"
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic == b"PK\x03\x04" and not zipfile.is_zipfile(path):
        return (f"truncated or not a PyTorch file ({size} bytes; the zip archive torch.save writes has no end "
                f"record: {_first_line(exc)})")
    if magic != b"PK\x03\x04":
        return f"truncated or not a PyTorch file ({size} bytes, not starting with the zip header torch.save writes)"
    return f"cannot read model checkpoint, truncated or corrupt ({size} bytes: {_first_line(exc)})"


def _model_config(path, ckpt: dict) -> ModelConfig:
    if not isinstance(ckpt["model_config"], dict):
        raise InputError(f"{path}: model_config must be a mapping, got {type(ckpt['model_config']).__name__}")
    try:
        return ModelConfig.from_dict(ckpt["model_config"], "model_config")
    except ConfigError as exc:
        raise InputError(f"{path}: bad model_config: {exc}") from None


def _check_state_dict(path, state: dict, model: ExposureNet) -> None:
    """Every key the architecture expects, with its shape; every problem in one message."""
    expected = model.state_dict()
    problems = [f"{k} missing" for k in expected if k not in state]
    problems += [f"unexpected key {k}" for k in state if k not in expected]
    problems += [f"{k} has shape {list(state[k].shape)}, expected {list(v.shape)}" for k, v in expected.items()
                 if k in state and tuple(state[k].shape) != tuple(v.shape)]
    if problems:
        shown = "; ".join(problems[:8]) + (f"; and {len(problems) - 8} more" if len(problems) > 8 else "")
        raise InputError(f"{path}: state_dict does not match model_config: {shown}")


def _check_sizes(path, ckpt: dict, cfg: ModelConfig) -> None:
    for key in ("input_hw", "store_hw"):
        v = ckpt[key]
        if not (isinstance(v, (list, tuple)) and len(v) == 2
                and all(isinstance(x, int) and not isinstance(x, bool) and 1 <= x <= 8192 for x in v)):
            raise InputError(f"{path}: {key} must be [height, width], two integers in 1–8192, got {v!r}")
    if tuple(ckpt["input_hw"]) != tuple(cfg.input_size):
        raise InputError(f"{path}: input_hw {list(ckpt['input_hw'])} differs from model_config.input_size "
                         f"{list(cfg.input_size)} (the network only takes the latter)")
    names = ckpt.get("channel_names")
    if names is not None and list(names) != list(CHANNEL_NAMES):
        raise InputError(f"{path}: channel_names {names} differ from this version's {list(CHANNEL_NAMES)}")


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return (text.splitlines()[0] if text else type(exc).__name__)[:300]


def export_onnx(model: ExposureNet, path, exporter: str = "torchscript") -> None:
    """Export (eval mode, dynamic batch) atomically.

    exporter "torchscript" (default): torch's TorchScript-based exporter — needs nothing beyond torch + onnx,
    works offline, deprecated since torch 2.9 but present in 2.13. "dynamo": the torch.export-based exporter, which
    needs `onnxscript` (tested with onnxscript 0.7.2 / onnx-ir 1.1.0); both give outputs equal to torch within 1e-4.
    """
    import warnings

    from expoctl.io import atomic_path

    if exporter not in ("torchscript", "dynamo"):
        raise ConfigError("train.onnx_exporter", f"must be torchscript or dynamo, got {exporter!r}")
    model = copy.deepcopy(model).eval()
    h, w = model.cfg.input_size
    example = torch.zeros(1, len(CHANNEL_NAMES), h, w)
    with atomic_path(path, suffix=".onnx") as tmp:
        if exporter == "dynamo":
            torch.onnx.export(model, (example,), str(tmp), input_names=["input"], output_names=["settings_norm"],
                              dynamic_shapes={"x": {0: torch.export.Dim("batch")}}, dynamo=True, verbose=False)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                torch.onnx.export(model, (example,), str(tmp), input_names=["input"], output_names=["settings_norm"],
                                  dynamic_axes={"input": {0: "batch"}, "settings_norm": {0: "batch"}},
                                  opset_version=17, dynamo=False)
