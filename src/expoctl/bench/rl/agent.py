"""What the agent sees and how a trained one is stored: the feature vector it acts on and its files.

The policy acts on a small vector computed from the environment's observation (`features`): the grey-level
histogram of the observed frame (`histogram_bins` bins, as fractions of its pixels) and the settings the frame was
exposed with, normalised as the action space normalises them (gain/30 dB; exposure on the `exposure_scale` scale).
Why not the image itself: at ~10 env steps/s on two cores a training budget is some 10^4 steps, too few for a CNN
from pixels; a histogram is what exposure control acts on (AG+AE's mean intensity, DRL-AE's inputs are image
statistics too). The same function serves training (`FeatureObs`, around the env) and the `rl` controller.

A trained agent is a folder (the train_rl stage's `models/rl`):
- `agent.zip`: the stable-baselines3 model (policy, optimiser, step count);
- `replay_buffer.pkl`: SAC's replay buffer, so a resumed run continues with its experience;
- `agent.json`: the `rl` config it was trained with (the environment's arguments, the feature settings), the steps
  done and the library versions: the controller rebuilds the observation from it;
- or, when the stage is off, only `DISABLED.json` (a marker: no agent was trained).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

AGENT_FILE, BUFFER_FILE, META_FILE, DISABLED_FILE = "agent.zip", "replay_buffer.pkl", "agent.json", "DISABLED.json"


def features(obs: dict[str, Any], bins: int, exposure_scale: str) -> np.ndarray:
    """The policy's input (float32, bins + 2) from the environment's observation (module doc)."""
    from expoctl.camera import ranges
    from expoctl.features.pipeline import rgb_to_grey

    grey = rgb_to_grey(obs["image"])
    hist = np.bincount(((grey.astype(np.int64) * bins) >> 8).ravel(), minlength=bins)[:bins] / grey.size
    gain_db, exposure_us = (float(v) for v in obs["settings"])
    settings = [float(ranges.gain_to_norm(gain_db)), float(ranges.exposure_to_norm(exposure_us, exposure_scale))]
    return np.concatenate([hist, settings]).astype(np.float32)


def feature_space(bins: int):
    from gymnasium import spaces

    # histogram fractions in [0, 1]; the normalised exposure reaches below 0 (the sensor's 19 µs floor)
    return spaces.Box(-1.0, 1.0, shape=(bins + 2,), dtype=np.float32)


def feature_env(env, bins: int, exposure_scale: str):
    """`env` (an ExposureEnv) with `features` as its observation."""
    import gymnasium as gym

    class FeatureObs(gym.ObservationWrapper):
        def __init__(self, inner):
            super().__init__(inner)
            self.observation_space = feature_space(bins)

        def observation(self, observation):
            return features(observation, bins, exposure_scale)

    return FeatureObs(env)


def agent_paths(folder: str | os.PathLike) -> dict[str, Path]:
    d = Path(folder)
    return {"agent": d / AGENT_FILE, "buffer": d / BUFFER_FILE, "meta": d / META_FILE, "disabled": d / DISABLED_FILE}


def read_meta(folder: str | os.PathLike) -> dict[str, Any] | None:
    p = agent_paths(folder)["meta"]
    return json.loads(p.read_text()) if p.is_file() else None


def algorithm_class(name: str):
    from stable_baselines3 import PPO, SAC

    return {"sac": SAC, "ppo": PPO}[name]


def load_agent(folder: str | os.PathLike):
    """(stable-baselines3 model, meta) of the trained agent in `folder` (InputError naming what is missing)."""
    from expoctl.errors import InputError

    paths = agent_paths(folder)
    if not paths["agent"].is_file() or not paths["meta"].is_file():
        why = ("the train_rl stage is off (rl.enabled: false): it wrote only a marker"
               if paths["disabled"].is_file() else "no trained agent there")
        raise InputError(f"{paths['agent']}: {why}; set rl.enabled: true and run `dvc repro train_rl` "
                         "(docs/benchmark.md, A reinforcement-learning baseline)")
    meta = read_meta(folder)
    model = algorithm_class(meta["config"]["algorithm"]).load(str(paths["agent"]), device="cpu")
    return model, meta
