"""Shared fixtures for the evaluate / oracle tests: a linear test sensor and a textured, moving, step-lit scene."""

from __future__ import annotations

import cv2
import numpy as np

from expoctl.sim.closed_loop import FunctionScene

K_DN = 25.6  # DN per (cd/m² · s · linear gain): 1000 cd/m² at 5 ms, 0 dB → 128 DN


class LinearSensor:
    """A linear 8-bit sensor: DN = clip(L · t · K_DN · 10^(g/20) + N(0, noise_dn²)); RGB = three equal channels.
    Deterministic given the generator (the interface the closed loop uses)."""

    def __init__(self, noise_dn: float = 1.0):
        self.noise_dn = noise_dn

    def capture(self, luminance_cd_m2, exposure_us, gain_db, rng):
        signal = luminance_cd_m2[..., 0] * (exposure_us * 1e-6) * K_DN * 10.0 ** (gain_db / 20.0)
        if self.noise_dn:
            signal = signal + rng.normal(0.0, self.noise_dn, signal.shape)
        grey = np.clip(np.rint(signal), 0, 255).astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)


def texture(h: int = 240, w: int = 400, seed: int = 0) -> np.ndarray:
    """Smooth random texture in [0.2, 1.8] (mean ~1): corners for ORB and the libviso2-style filters."""
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.random((h, w)).astype(np.float32), (0, 0), 1.5)
    t = (t - t.min()) / (t.max() - t.min())
    return 0.2 + 1.6 * t


def moving_scene(level_cd_m2, width: int = 160, height: int = 120, step_px: int = 2, fps: float = 15.0):
    """FunctionScene: a `width`×`height` crop of a texture sliding `step_px` per frame, scaled by level_cd_m2(frame)."""
    tex = texture(height + 20, width + 400)

    def lum(frame, exposure_us, camera):
        x0 = (frame * step_px) % 400
        crop = tex[10:10 + height, x0:x0 + width] * float(level_cd_m2(frame))
        return np.repeat(crop[..., None], 3, axis=2).astype(np.float32)

    return FunctionScene(lum, fps)


# ---------------------------------------------------------------------------------------------- fixture-scale project

REPO = __import__("pathlib").Path(__file__).resolve().parents[1]


def make_fixture_project(root, controllers=None, n_jobs: int = 1) -> dict:
    """A tiny evaluation project under `root`: train-split frames (PNGs + frames.parquet) for SumLog tuning, a small
    untrained learned-controller checkpoint, and a resolved config at fixture scale (96×72 renders, 256 px texture
    tiles, short portal windows with short dynamic spans). Returns the config dict."""
    from pathlib import Path

    import pandas as pd
    import torch

    from expoctl.io import write_png
    from expoctl.net.model import ExposureNet, ModelConfig
    from expoctl.net.train import TrainConfig, TrainResult
    from expoctl.net.checkpoint import checkpoint_dict

    root = Path(root)
    rows = []
    tex = texture(72, 140, seed=3)
    for k in range(4):
        img = np.clip(tex[:, k * 4:k * 4 + 96] * 110, 0, 255).astype(np.uint8)
        p = f"data/raw/train/s0/cam1/{k:06d}.png"
        write_png(np.repeat(img[..., None], 3, axis=2), root / p)
        rows.append({"sequence": "s0", "frame_id": k, "camera": 1, "timestamp_ns": k, "gain_db": 0.0,
                     "exposure_us": 1000.0, "image_path": p, "split": "train", "section": "static", "image_index": k})
    (root / "data").mkdir(exist_ok=True)
    pd.DataFrame(rows).to_parquet(root / "data/frames.parquet", index=False)
    mcfg = ModelConfig.from_dict({"input_size": 32, "conv_widths": [4, 4, 8, 8], "conv_kernels": [3, 3, 3],
                                  "pool": 2, "fc_widths": [8, 8, 8], "dropout": 0.0})
    torch.manual_seed(0)
    ckpt = checkpoint_dict(TrainResult(ExposureNet(mcfg).eval(), 0, 0, [], {}), mcfg, TrainConfig(), (48, 64), 0)
    (root / "models").mkdir(exist_ok=True)
    torch.save(ckpt, root / "models/controller.pt")
    short = {"dynamic_before_s": 0.3, "dynamic_after_s": 0.3}
    city = lambda base: {"base": base, "textures": {"tile_px": 256}, "traversal": short}  # noqa: E731
    window = {"window": "portal", "before_s": 0.6, "after_s": 0.6, "windows": [1]}
    return {
        "seed": 0,
        "numerics": {"mode": "pinned"},  # conf/numerics/default.yaml: every computing stage selects it
        "scale_name": "fixture",
        "sensor": {},
        "rig": {},
        "world": {"cities": {"validation": city("validation"), "test": city("test")},
                  "city_dir": str(REPO / "conf/world/cities"), "render": {"width": 96, "height": 72, "hfov_deg": 70.0}},
        "controllers": {"fixed": {"mode": "manual", "gain_db": 0.0, "exposure_us": 2000.0},
                        "oracle": {"exposures_us": [30000.0, 3750.0, 469.0, 117.0], "gains_db": [12.0, 24.0],
                                   "match_width": 96, "match_nfeatures": 300}},
        "features": {"orb": {"working_size": None, "count_nfeatures": 500, "match_nfeatures": 500},
                     "sumlog": {"alphas": [[0.333333, 0.333333, 0.333334], [0.0, 1.0, 0.0]], "betas": [2.0, 8.0],
                                "max_pairs": 3}},
        "evaluate": {"controllers": list(controllers or ("agae", "shin", "shim", "mean_intensity", "fixed", "learned",
                                                         "oracle")),
                     "splits": {"validation": window, "test": window}, "warmup_frames": 2, "sumlog_pairs": 3,
                     "min_section_frames": 3, "vo": {"min_inliers": 8, "n_features": 500}, "thumb_width": 48,
                     "thumb_span_s": 1.0},
        # n_jobs picks in-process (1) or worker processes on this host, as conf/parallel/default.yaml does
        "parallel": {"backend": "processes", "address": None, "n_jobs": n_jobs},
        "report": {"strip_split": "test", "strip_portal": "exit", "strip_columns": 4},
        # the evaluate stage drives the pipeline's final model (select_model's choice; here the one fixture model)
        "paths": {"frames": "data/frames.parquet", "model": "models/controller.pt", "reports_dir": "reports",
                  "final_model": "models/controller.pt"},
        "plugins": {"controllers": {}, "frontends": {}},  # what compose records (stages/table.py recorded_plugins)
    }


def constant_network(src, dst, gain_db: float, exposure_us: float, onnx: bool = False):
    """A copy of the checkpoint at `src` whose output ignores the image: always (gain_db, exposure_us); with `onnx`
    also its ONNX export beside it."""
    import torch

    from expoctl.camera.ranges import exposure_to_norm, gain_to_norm
    from expoctl.net.train import TrainConfig, TrainResult
    from expoctl.net.checkpoint import checkpoint_dict, export_onnx, load_checkpoint

    model, ckpt = load_checkpoint(src)
    out = model.head[-1]
    with torch.no_grad():
        out.weight.zero_()
        out.bias.copy_(torch.tensor([float(gain_to_norm(gain_db)), float(exposure_to_norm(exposure_us))]))
    torch.save(checkpoint_dict(TrainResult(model, 0, 0, [], {}), model.cfg, TrainConfig(), ckpt["store_hw"], 0), dst)
    if onnx:
        export_onnx(model.eval(), dst.with_suffix(".onnx"))
    return dst


def selection_project(root) -> tuple[dict, list]:
    """The fixture project plus a small train city, a one-window `select_model` plan and two constant networks:
    a well-exposing one (iteration 1) and one stuck in saturation (iteration 2). Returns (config, candidates)."""
    from pathlib import Path

    from expoctl.selection.model_selection import Candidate

    root = Path(root)
    cfg = make_fixture_project(root, controllers=["agae", "learned"])
    short = {"dynamic_before_s": 0.3, "dynamic_after_s": 0.3}
    cfg["world"]["cities"]["train"] = {"base": "train", "textures": {"tile_px": 256}, "traversal": short}
    cfg["select_model"] = {"enabled": True, "window": "portal", "before_s": 0.6, "after_s": 0.6,
                           "windows": [1],  # tunnel 0's exit
                           "probe": {"frames": 6, "width": 64, "height": 48, "first_frames": 2, "last_frames": 2}}
    cfg["evaluate"]["render_size"] = [160, 120]  # at 96×72 the train city's textures give ORB almost nothing
    models = root / "models"
    # iteration 1 holds a daylight-sized setting (AG+AE settles at ~140 µs, 0 dB on this window's open road);
    # iteration 2 (the later one, which the paper would keep) is stuck at the longest exposure and highest gain
    good = constant_network(models / "controller.pt", models / "good.pt", 0.0, 150.0, onnx=True)
    white = constant_network(models / "controller.pt", models / "white.pt", 30.0, 30000.0, onnx=True)
    # the same two as the pipeline's iterations (for the stage); iteration 3 is off, so not a candidate
    cfg["paths"].update(model="models/good.pt", final_model="models/controller_final.pt")
    cfg["iteration2"] = {"enabled": True, "paths": {"model": "models/white.pt"}}
    cfg["iteration3"] = {"enabled": False, "paths": {"model": "models/white.pt"}}
    return cfg, [Candidate("iteration1", 1, good), Candidate("iteration2", 2, white)]


def use_real_or_test_sensor(monkeypatch) -> str:
    """The simulator's sensor when it exists; until `expoctl.camera.sensor` lands, a `LinearSensor` stand-in."""
    try:
        import expoctl.camera.sensor  # noqa: F401

        return "real"
    except ImportError:
        import expoctl.sim.closed_loop as cl

        monkeypatch.setattr(cl, "make_sensors", lambda cfg, render, n, amp, seed: ([LinearSensor(2.0)] * n, {}))
        return "linear stand-in"
