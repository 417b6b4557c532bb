"""The controller network: the one preprocessing path from camera frames to its input (`preprocess`), the model
(`model`), the training data (`dataset`), training (`train`), the checkpoint and its ONNX export (`checkpoint`) and
the open-loop camera-follow probe (`follow`).
"""

from expoctl.net.checkpoint import checkpoint_dict, export_onnx, load_checkpoint
from expoctl.net.dataset import load_sample_sets_from_files, predict
from expoctl.net.model import ModelConfig, scale_widths
from expoctl.net.preprocess import N_FRAMES, assemble_input, prepare_frame, settings_to_norm, stack_frames
from expoctl.net.train import TrainConfig, fit

__all__ = ["N_FRAMES", "ModelConfig", "TrainConfig", "assemble_input", "checkpoint_dict", "export_onnx", "fit",
           "load_checkpoint", "load_sample_sets_from_files", "predict", "prepare_frame", "scale_widths",
           "settings_to_norm", "stack_frames"]
