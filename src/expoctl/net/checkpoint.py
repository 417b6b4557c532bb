"""The controller checkpoint (models/controller.pt: weights, architecture, preprocessing sizes) and its ONNX export.

`checkpoint_dict` builds it from a training result (`expoctl.net.train`), `load_checkpoint` reads it back (the
deployed controller, `expoctl.controllers.learned`), `export_onnx` writes the network as ONNX.
"""

from __future__ import annotations

import copy
from dataclasses import asdict
from typing import TYPE_CHECKING

import numpy as np
import torch

from expoctl.errors import ConfigError
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
    """Load models/controller.pt → (model in eval mode, checkpoint metadata)."""
    from expoctl.errors import InputError

    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise InputError(f"{path}: model checkpoint not found") from None
    except Exception as exc:
        raise InputError(f"{path}: cannot read model checkpoint ({exc})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{path}: not an expoctl controller checkpoint (format {CHECKPOINT_FORMAT} expected)")
    model = ExposureNet(ModelConfig.from_dict(ckpt["model_config"]))
    model.load_state_dict(ckpt["state_dict"])
    model.eval()
    return model, ckpt


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
