"""Train the reinforcement-learning baseline in `expoctl/Exposure-v0` on the training city only, resumably.

`train(config, out_dir, ...)`: a stable-baselines3 SAC or PPO agent (`rl.algorithm`) on `ExposureEnv(split="train")`
(stretches of the training city under the `bench-train` seeds: never an evaluation window, expoctl.bench.episodes),
its observation turned into the agent's feature vector (expoctl.bench.rl.agent). Every `checkpoint_every` steps and at the
end it writes the agent folder (agent.zip, SAC's replay buffer, agent.json), each file replaced atomically, so an
interrupted run leaves its last checkpoint. A later call on the same folder continues from the saved step count up
to the new `total_steps` (the environment and learner keys must match the checkpoint's; `total_steps`,
`checkpoint_every`, `log_every` and `torch_threads` may change).

Determinism: a fresh run is a function of `rl.seed` (SB3 seeds python, numpy, torch and the action space; the env's
episode draws are seeded from it; torch runs single-threaded on CPU by default) — tested: two runs write the same
agent. A resumed run is not bit-identical to one uninterrupted run: SB3's checkpoint holds the weights, optimiser
and replay buffer, not the RNG states of torch, numpy or the environment's episode draws, which restart from the
seed offset by the step count.

No Hydra, DVC or MLflow here: `log_metrics(metrics, step)` is the caller's (the train_rl stage logs to MLflow).
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from expoctl.errors import InputError
from expoctl.bench.rl.agent import agent_paths, algorithm_class, feature_env, read_meta
from expoctl.bench.rl.config import RLConfig

log = logging.getLogger(__name__)

#: keys that may differ between a checkpoint and the run that resumes it (they change no learned byte's meaning)
RESUMABLE_CHANGES = ("enabled", "total_steps", "checkpoint_every", "log_every", "torch_threads")


def make_train_env(config: RLConfig, env_config: str | os.PathLike | Mapping | None = None, scale: str = "default",
                   project_root: str | os.PathLike | None = None):
    """The training environment: the train split only, with the agent's feature observation."""
    from expoctl.bench.env import ExposureEnv

    env = ExposureEnv("train", config=env_config, scale=scale, project_root=project_root, **config.env_kwargs())
    return feature_env(env, config.histogram_bins, config.exposure_scale)


def _new_model(config: RLConfig, env):
    cls = algorithm_class(config.algorithm)
    common = dict(learning_rate=config.learning_rate, gamma=config.gamma, seed=config.seed, device="cpu",
                  policy_kwargs={"net_arch": [int(n) for n in config.net_arch]}, verbose=0)
    if config.algorithm == "sac":
        return cls("MlpPolicy", env, buffer_size=config.buffer_size, learning_starts=config.learning_starts,
                   batch_size=config.batch_size, **common)
    return cls("MlpPolicy", env, n_steps=config.n_steps, batch_size=min(config.batch_size, config.n_steps), **common)


def _atomic(path: Path, write: Callable[[Path], None]) -> None:
    tmp = path.with_name(path.name + ".tmp" + path.suffix)
    write(tmp)
    os.replace(tmp, path)


def save_checkpoint(model, config: RLConfig, out_dir: Path, extra: dict[str, Any]) -> None:
    import stable_baselines3
    import torch

    paths = agent_paths(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths["disabled"].unlink(missing_ok=True)
    # SB3 appends .zip / .pkl to a name without them: give it the full temporary name
    _atomic(paths["agent"], lambda p: model.save(str(p)))
    if hasattr(model, "replay_buffer") and model.replay_buffer is not None:
        _atomic(paths["buffer"], lambda p: model.save_replay_buffer(str(p)))
    meta = {"config": config.as_dict(), "steps": int(model.num_timesteps), **extra,
            "versions": {"stable_baselines3": stable_baselines3.__version__, "torch": torch.__version__}}
    _atomic(paths["meta"], lambda p: p.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n"))


def _check_resumable(saved: dict, config: RLConfig, where: Path) -> None:
    now = config.as_dict()
    differ = [k for k in sorted(set(now) | set(saved)) if k not in RESUMABLE_CHANGES and saved.get(k) != now.get(k)]
    if differ:
        raise InputError(f"{where}: the checkpoint was trained with other settings (rl.{differ[0]}: "
                         f"{saved.get(differ[0])!r}, now {now.get(differ[0])!r}; differing: "
                         f"{', '.join('rl.' + k for k in differ)}); delete {where} to start over")


def write_disabled(out_dir: str | os.PathLike) -> Path:
    """The marker of a disabled train_rl stage: the folder holds DISABLED.json and no agent."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = agent_paths(out)
    for key in ("agent", "buffer", "meta"):
        paths[key].unlink(missing_ok=True)
    paths["disabled"].write_text(json.dumps({"enabled": False, "why": "rl.enabled is false: no agent trained; "
                                             "evaluate and bench skip the rl controller"}, indent=2) + "\n")
    return paths["disabled"]


def train(config: RLConfig, out_dir: str | os.PathLike, env_config: str | os.PathLike | Mapping | None = None,
          scale: str = "default", project_root: str | os.PathLike | None = None,
          log_metrics: Callable[[dict[str, float], int], None] | None = None) -> dict[str, Any]:
    """Train (or continue training) up to `config.total_steps` env steps; returns a summary (steps, seconds,
    steps/s, episodes). See the module doc."""
    import torch
    from stable_baselines3.common.callbacks import BaseCallback

    out = Path(out_dir)
    torch.set_num_threads(config.torch_threads)
    env = make_train_env(config, env_config, scale, project_root)
    paths = agent_paths(out)
    meta = read_meta(out) if paths["agent"].is_file() else None
    history: list[dict[str, float]] = list(meta.get("episodes", [])) if meta else []
    if meta is not None:
        _check_resumable(meta["config"], config, out)
        model = algorithm_class(config.algorithm).load(str(paths["agent"]), env=env, device="cpu")
        if paths["buffer"].is_file() and hasattr(model, "load_replay_buffer"):
            model.load_replay_buffer(str(paths["buffer"]))
        # a resumed run draws on from another point of the seed (module doc: not bit-identical)
        model.set_random_seed(config.seed + int(model.num_timesteps))
        log.info("resuming %s at step %d of %d", paths["agent"], model.num_timesteps, config.total_steps)
    else:
        model = _new_model(config, env)
    start = int(model.num_timesteps)
    remaining = config.total_steps - start
    t0 = time.perf_counter()

    class Progress(BaseCallback):
        """Episode rewards and NFM to `log_metrics`; a checkpoint every checkpoint_every steps."""

        def __init__(self):
            super().__init__()
            self.ep_reward, self.ep_nfm, self.window_rewards = 0.0, [], []
            self.t_last, self.n_last = time.perf_counter(), 0

        def _on_step(self) -> bool:
            step = int(self.num_timesteps)
            reward = float(self.locals["rewards"][0])
            info = self.locals["infos"][0]
            self.ep_reward += reward
            self.window_rewards.append(reward)
            if not info.get("warmup", False):
                self.ep_nfm.append(float(info["nfm"][config.frontend]))
            if log_metrics is not None and step % config.log_every == 0:
                now = time.perf_counter()
                log_metrics({"reward_mean": float(np.mean(self.window_rewards)),
                             "steps_per_s": (step - start - self.n_last) / max(now - self.t_last, 1e-9)}, step)
                self.window_rewards, self.t_last, self.n_last = [], now, step - start
            if bool(self.locals["dones"][0]):
                nfm = np.asarray(self.ep_nfm or [0.0])
                ep = {"step": step, "episode_reward": self.ep_reward, "episode_nfm_mean": float(nfm.mean()),
                      "episode_nfm_min": float(nfm.min()), "episode_window": int(info.get("window", -1))}
                history.append(ep)
                if log_metrics is not None:
                    log_metrics({k: v for k, v in ep.items() if k != "step"}, step)
                log.info("step %d: episode %d reward %.2f, NFM mean %.0f min %.0f", step, len(history),
                         self.ep_reward, ep["episode_nfm_mean"], ep["episode_nfm_min"])
                self.ep_reward, self.ep_nfm = 0.0, []
            if step % config.checkpoint_every == 0:
                save_checkpoint(self.model, config, out, {"episodes": history})
            return True

    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=Progress(), reset_num_timesteps=meta is None,
                    progress_bar=False)
    seconds = time.perf_counter() - t0
    save_checkpoint(model, config, out, {"episodes": history})
    env.close()
    done = int(model.num_timesteps) - start
    summary = {"steps": int(model.num_timesteps), "steps_this_run": done, "resumed_from": start,
               "seconds": seconds, "steps_per_s": done / max(seconds, 1e-9), "episodes": len(history)}
    log.info("trained %d steps (from %d) in %.0f s, %.2f steps/s -> %s", done, start, seconds,
             summary["steps_per_s"], out)
    return summary
