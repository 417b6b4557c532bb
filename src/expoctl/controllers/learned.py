"""The learned controller (Tomasi et al. 2021): the trained CNN behind the shared `Controller` interface.

Per frame: the full-size 8-bit RGB camera frame goes through `expoctl.net.preprocess.prepare_frame` — the ingest resize
(INTER_AREA to the image-store size recorded in the checkpoint), then to the network input size — exactly the
chain the training frames went through. The controller keeps the last three prepared frames and their settings;
until three frames exist it repeats the oldest one (the start of a sequence). The network's two outputs are
clamped to [0, 1] and unscaled (`expoctl.camera.ranges`, with the exposure scaling the model was trained with); the caller applies them at frame t+1.

Driving a real camera (any SDK that can read a frame with its gain/exposure and set the next ones):

    from expoctl.controllers.base import Settings
    from expoctl.controllers.learned import LearnedController

    ctrl = LearnedController.from_checkpoint("models/controller.pt", num_threads=1)   # or backend="onnx"
    ctrl.reset(Settings(gain_db=cam.gain_db, exposure_us=cam.exposure_us))
    while running:
        frame = cam.grab()                               # H×W×3 uint8 RGB (convert BGR/Bayer first)
        applied = Settings(frame.gain_db, frame.exposure_us)   # what the frame was captured with (chunk data)
        nxt = ctrl.update(frame.rgb, applied)
        cam.set_gain_db(nxt.gain_db); cam.set_exposure_us(nxt.exposure_us)   # takes effect at the next frame

Use the settings the frame was actually captured with (from the camera's per-frame metadata), not the last command.

`allocation` (config `controllers.learned.allocation`): "network" commands the network's gain and exposure as they
are (the paper). "exposure_first" keeps the network's total exposure product t·10^(g/20) — the image brightness it
asked for — but spends it on exposure time first and on gain only beyond 30 ms, as AG+AE does: less noise for the
same signal, at the cost of motion blur. It exists because the iteration-2 network drifts to +7–10 dB gain at
sub-millisecond exposures in daylight (docs/runs/old_camera_results.md).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from expoctl.camera.ranges import norm_to_exposure, norm_to_gain
from expoctl.controllers.agae import ln_exposure_product, split_exposure_first
from expoctl.config_reader import Problems, param, read_config
from expoctl.controllers.base import LATENCY_FRAMES_MIN, Controller, DelayedController, Settings
from expoctl.controllers.registry import ControllerContext, register_controller
from expoctl.errors import ConfigError
from expoctl.net.preprocess import N_FRAMES, assemble_input, prepare_frame, settings_to_norm, stack_frames


ALLOCATIONS = ("network", "exposure_first")


def exposure_first(settings: Settings) -> Settings:
    """The same total exposure product t·10^(g/20), with the gain moved into exposure time up to 30 ms (AG+AE's
    exposure-first split)."""
    return split_exposure_first(ln_exposure_product(settings))


class LearnedController(Controller):
    name = "learned"

    def __init__(self, model: torch.nn.Module, store_hw, input_hw, num_threads: int | None = 1,
                 onnx_session=None, exposure_scale: str | None = None, allocation: str = "network"):
        if allocation not in ALLOCATIONS:
            raise ConfigError("controllers.learned.allocation", f"must be one of {list(ALLOCATIONS)}, got {allocation!r}")
        self.allocation = allocation
        self.model = model.eval()
        # the scaling the network was trained with (model.exposure_scale, recorded in its config)
        self.exposure_scale = exposure_scale or getattr(getattr(model, "cfg", None), "exposure_scale", "linear")
        self.store_hw = tuple(int(v) for v in store_hw)
        self.input_hw = tuple(int(v) for v in input_hw)
        self.num_threads = num_threads
        self.onnx_session = onnx_session
        self._frames: deque = deque(maxlen=N_FRAMES)
        self._settings: deque = deque(maxlen=N_FRAMES)

    @classmethod
    def from_checkpoint(cls, path, num_threads: int | None = 1, backend: str = "torch",
                        allocation: str = "network") -> "LearnedController":
        """Load models/controller.pt; backend "onnx" runs the exported models/controller.onnx beside it.

        A bad file raises `InputError` naming it and the problem, with the same checks and words as the stages' start
        check (`expoctl.net.checkpoint.check_checkpoint`): truncated, not a checkpoint, weights that do not match
        model_config, an .onnx that is missing, does not load or takes another input shape."""
        from expoctl.net.checkpoint import load_checkpoint, onnx_session

        if backend not in ("torch", "onnx"):
            raise ConfigError("controllers.learned.backend", f"must be torch or onnx, got {backend!r}")
        model, ckpt = load_checkpoint(path)
        session = None
        if backend == "onnx":
            session = onnx_session(Path(path).with_suffix(".onnx"), ckpt["input_hw"], num_threads)
        return cls(model, ckpt["store_hw"], ckpt["input_hw"], num_threads=num_threads, onnx_session=session,
                   exposure_scale=model.cfg.exposure_scale, allocation=allocation)

    def reset(self, initial: Settings) -> None:
        self._frames.clear()
        self._settings.clear()

    def network_input(self, image: np.ndarray, applied: Settings) -> torch.Tensor:
        """Push frame t into the history and return the (1, 15, h, w) input (exposed for the agreement test)."""
        frame = prepare_frame(image, self.store_hw, self.input_hw)
        self._frames.appendleft(frame)  # index 0 = t, 1 = t−1, 2 = t−2
        self._settings.appendleft(applied)
        while len(self._frames) < N_FRAMES:  # sequence start: repeat the oldest frame we have
            self._frames.append(self._frames[-1])
            self._settings.append(self._settings[-1])
        g, e = settings_to_norm([s.gain_db for s in self._settings], [s.exposure_us for s in self._settings],
                                self.exposure_scale)
        return assemble_input(stack_frames(list(self._frames)), torch.from_numpy(g)[None], torch.from_numpy(e)[None])

    def predict_norm(self, x: torch.Tensor) -> np.ndarray:
        if self.onnx_session is not None:
            return self.onnx_session.run(None, {"input": x.numpy()})[0][0]
        if self.num_threads and torch.get_num_threads() != self.num_threads:
            torch.set_num_threads(self.num_threads)
        with torch.no_grad():
            return self.model(x)[0].numpy()

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        out = self.predict_norm(self.network_input(image, applied))
        # clamp to [0, 1] then unscale (norm_to_* clamp first)
        nxt = Settings(float(norm_to_gain(out[0])), float(norm_to_exposure(out[1], self.exposure_scale)))
        return exposure_first(nxt) if self.allocation == "exposure_first" else nxt


@dataclass(frozen=True)
class LearnedConfig:
    """`controllers.learned`, checked without loading the checkpoint (compose checks it before any network exists).

    `latency_frames` (simulator only): the network's settings computed from frame t expose frame t + latency_frames
    (1: the paper's rig; 2: the calibrated camera's earliest, docs/calibration.md). Train with the same value
    (`labels.latency_frames` follows it), so the labels target the frames the command can still change."""

    checkpoint: str | None = None  # the network evaluate drives; null: paths.final_model (the stage decides)
    backend: str = param("torch", choices=("torch", "onnx"))  # whether the .onnx exists is checked with the checkpoint
    num_threads: int | None = param(1, min=1)
    allocation: str = param("network", choices=ALLOCATIONS)
    latency_frames: int = param(1, min=LATENCY_FRAMES_MIN)


def _build_learned(config: LearnedConfig, context: ControllerContext) -> Controller:
    """The network from `context.checkpoint` (its .onnx beside it for backend onnx), delayed by latency_frames."""
    path = context.checkpoint or config.checkpoint or "models/controller.pt"
    ctrl = LearnedController.from_checkpoint(path, num_threads=config.num_threads,
                                             backend=config.backend, allocation=config.allocation)
    return ctrl if config.latency_frames == 1 else DelayedController(ctrl, config.latency_frames)


register_controller("learned", config=LearnedConfig, factory=_build_learned, needs=("checkpoint",), label="Ours",
                    colour="#1f77b4", rank=60)(LearnedController)


def make_learned(params: dict | LearnedConfig) -> Controller:
    """The learned controller from its config section, whose `checkpoint` names the network
    (default models/controller.pt)."""
    config = params if isinstance(params, LearnedConfig) else read_config(LearnedConfig, params, "controllers.learned")
    return _build_learned(config, ControllerContext(checkpoint=config.checkpoint or "models/controller.pt"))


def read_learned_params(params: dict | None, problems: Problems | None = None) -> dict:
    """The `controllers.learned` keys as a dict {path, backend, num_threads, allocation, latency_frames} (default
    path models/controller.pt); with `problems`, problems are added there for the caller to raise."""
    config = read_config(LearnedConfig, params, "controllers.learned", problems)
    return {"path": config.checkpoint or "models/controller.pt", "backend": config.backend,
            "num_threads": config.num_threads, "allocation": config.allocation,
            "latency_frames": config.latency_frames}
