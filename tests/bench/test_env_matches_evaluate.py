"""A built-in controller driven through the environment gets exactly what evaluate gives it on the same window:
the same frames (byte for byte, warm-up included), settings and per-frame NFM (orb and viso)."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from expoctl.bench.env import ExposureEnv
from expoctl.bench.policy import ControllerPolicy
from expoctl.controllers.registry import make_controller
from expoctl.evaluation.run import WindowRun
from expoctl.evaluation.runner import RunJob, plan_windows, run_window
from expoctl.features.sumlog import SumLogParams


def _digest(img: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(img).tobytes()).hexdigest()


def _evaluate(env: ExposureEnv, controller: str, monkeypatch):
    """evaluate's own run of `controller` on the environment's window: its rows, and every frame its closed loop
    yielded (warm-up included) as (trajectory frame, image digest, settings)."""
    frames = []
    record = WindowRun.record

    def spy(self, rig_frame):
        cam = rig_frame.camera(1)
        frames.append((rig_frame.frame_index, _digest(cam.image), cam.settings))
        record(self, rig_frame)

    monkeypatch.setattr(WindowRun, "record", spy)
    sumlog = {f: SumLogParams() for f in env.inputs.evaluate.frontends}  # SumLog columns are not compared
    [(rows, _, _)] = run_window((RunJob(env.window, controller, env.inputs, sumlog),))
    monkeypatch.setattr(WindowRun, "record", record)
    return rows, frames


def _drive(env: ExposureEnv, controller: str, window: int):
    policy = ControllerPolicy(make_controller(controller, env.inputs.controller_config(controller)), env)
    obs, info = env.reset(options={"window": window})
    policy.reset(obs)
    steps = [(obs, info)]
    terminated = False
    while not terminated:
        obs, _, terminated, _, info = env.step(policy(obs))
        steps.append((obs, info))
    return steps


@pytest.mark.parametrize("action", ["ev_step", "settings"])
def test_agae_through_the_env_is_evaluate_byte_for_byte(action, monkeypatch):
    env = ExposureEnv("validation", scale="fixture", action=action, info_frontends=["viso"])
    steps = _drive(env, "agae", window=0)
    # the episode's window is evaluate's first validation window, with its seeds
    assert env.window == plan_windows(env.inputs)[0]
    rows, frames = _evaluate(env, "agae", monkeypatch)

    assert len(steps) == len(frames) == env.window.stop - env.window.start + env.inputs.evaluate.warmup_frames
    for (obs, info), (t, digest, settings) in zip(steps, frames):
        assert info["traj_frame"] == t
        assert _digest(obs["image"]) == digest
        assert (info["settings"]["gain_db"], info["settings"]["exposure_us"]) == (settings.gain_db,
                                                                                  settings.exposure_us)
        assert tuple(obs["settings"]) == (settings.gain_db, settings.exposure_us)
    recorded = [info for _, info in steps if not info["warmup"]]
    assert [i["frame"] for i in recorded] == [r["frame"] for r in rows]
    for info, row in zip(recorded, rows):
        assert (info["settings"]["gain_db"], info["settings"]["exposure_us"]) == (row["gain_db"], row["exposure_us"])
        assert info["timestamp_ns"] == row["timestamp_ns"] and info["section"] == row["section"]
    # evaluate has no pair before the window's first frame; the environment's has the last warm-up frame
    for fe in ("orb", "viso"):
        env_nfm = [i["nfm"][fe] for i in recorded[1:]]
        assert env_nfm == [r[f"nfm_{fe}"] for r in rows[1:]]
        assert len(set(env_nfm)) > 1  # a real series, not a constant
    # the controller moved the settings: the comparison covers a closed loop, not a fixed exposure
    assert len({i["settings"]["exposure_us"] for _, i in steps}) > 3
