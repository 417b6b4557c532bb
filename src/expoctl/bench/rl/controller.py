"""The reinforcement-learning baseline as a controller: a stable-baselines3 agent trained in `expoctl/Exposure-v0`
(`expoctl.bench.rl.train`, the optional train_rl stage), driven wherever a controller is (evaluate, `expoctl bench`).

Per frame it does what the environment does around the agent: the observation from the frame and the settings it
was exposed with (`expoctl.bench.env.observation`: the same resize to the training obs_size), the agent's feature
vector (`expoctl.bench.rl.agent.features`), the policy's deterministic action, and that action's settings
(`expoctl.bench.actions.ActionMap`, the training action mode) applied at the next frame (the env's one frame of
latency). Everything it rebuilds comes from the agent folder's agent.json, so it cannot drift from training.

Opt-in (`opt_in=True`): `evaluate.controllers: null` and `expoctl bench` include it only where a trained agent
exists (the train_rl stage is off by default and then writes only a marker); named explicitly without an agent it
is an error naming the folder.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from expoctl.controllers.base import Controller, Settings
from expoctl.controllers.registry import ControllerContext, register_controller

log = logging.getLogger(__name__)

#: the train_rl stage's output folder, relative to the project root
DEFAULT_AGENT_DIR = "models/rl"


@dataclass(frozen=True)
class RLControllerConfig:
    """`controllers.rl`: `agent`, the trained agent's folder (relative: to the project root / working directory)."""

    agent: str = DEFAULT_AGENT_DIR


class RLController(Controller):
    name = "rl"

    def __init__(self, model, meta: dict):
        from expoctl.bench.actions import ActionMap

        cfg = meta["config"]
        self.model, self.meta = model, meta
        self.render_size = tuple(cfg["render_size"])
        self.obs_size = None if cfg["obs_size"] is None else tuple(cfg["obs_size"])
        self.bins, self.exposure_scale = int(cfg["histogram_bins"]), cfg["exposure_scale"]
        self.actions = ActionMap(cfg["action"], cfg["exposure_scale"], cfg["max_ev_step"])
        self._warned = False

    @classmethod
    def from_folder(cls, folder) -> "RLController":
        from expoctl.bench.rl.agent import load_agent

        return cls(*load_agent(folder))

    def reset(self, initial: Settings) -> None:
        pass  # the policy is memoryless: it acts on the current frame only, as in training

    def features(self, image: np.ndarray, applied: Settings) -> np.ndarray:
        """The policy's input for frame t, exactly as the training environment built it."""
        from expoctl.bench.env import observation
        from expoctl.bench.rl.agent import features

        if (image.shape[1], image.shape[0]) != self.render_size and not self._warned:
            log.warning("rl: frames are %dx%d, the agent was trained on %dx%d renders: its observations differ "
                        "from training's (score it at the training size)", image.shape[1], image.shape[0],
                        *self.render_size)
            self._warned = True
        return features(observation(image, applied, self.obs_size), self.bins, self.exposure_scale)

    def action(self, image: np.ndarray, applied: Settings) -> np.ndarray:
        act, _ = self.model.predict(self.features(image, applied), deterministic=True)
        return np.asarray(act, dtype=np.float64)

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        return self.actions.settings_of(self.action(image, applied), applied)


def _build_rl(config: RLControllerConfig, context: ControllerContext) -> Controller:
    return RLController.from_folder(Path(config.agent))


register_controller("rl", config=RLControllerConfig, factory=_build_rl, label="RL (SAC)", colour="#8c564b",
                    rank=65, opt_in=True)(RLController)


def agent_folder(cfg: dict, root) -> Path:
    """The `rl` agent folder a resolved config names (`controllers.rl.agent`), relative paths under `root`."""
    section = ((cfg.get("controllers") or {}).get("rl") or {})
    folder = Path(section.get("agent") or DEFAULT_AGENT_DIR)
    return folder if folder.is_absolute() else Path(root) / folder


def with_rl(cfg: dict, root, names: list[str] | None = None) -> tuple[dict, str | None]:
    """(`cfg` with the `rl` controller settled, why `rl` is skipped or None) for a run over `names` (default: the
    config's `evaluate.controllers`; null there: every default controller). `rl` named explicitly needs a trained
    agent (InputError naming the folder); implicitly (null) it joins only when one exists, else it is skipped with
    the reason (the train_rl stage off: its marker). The agent's path is made absolute, for workers elsewhere."""
    import copy

    from expoctl.controllers.registry import controller_names
    from expoctl.errors import InputError
    from expoctl.bench.rl.agent import agent_paths

    cfg = copy.deepcopy(cfg)
    ev = cfg.setdefault("evaluate", {})
    explicit = names is not None or ev.get("controllers") is not None
    chosen = list(names if names is not None else (ev.get("controllers") or controller_names()))
    folder = agent_folder(cfg, root)
    paths = agent_paths(folder)
    have = paths["agent"].is_file() and paths["meta"].is_file()
    why = None
    if explicit and "rl" in chosen and not have:
        what = ("the train_rl stage is off (rl.enabled: false; it wrote only its marker)"
                if paths["disabled"].is_file() else "no trained agent there")
        raise InputError(f"{folder}: controller 'rl' is listed but {what}; train it (rl.enabled: true, "
                         "`dvc repro train_rl`) or drop 'rl' from the controllers")
    if not explicit:
        if have:
            chosen = [n for n in controller_names(opt_in=True) if n in chosen or n == "rl"]
        else:
            why = (f"no trained agent at {folder}" + (" (the train_rl stage is off: rl.enabled false)"
                                                      if paths["disabled"].is_file() else ""))
        ev["controllers"] = chosen
    if "rl" in chosen:
        cfg.setdefault("controllers", {}).setdefault("rl", {})["agent"] = str(folder.resolve())
    return cfg, why
