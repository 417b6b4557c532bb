"""A registered controller as a policy of the environment: what a controller would command, as an action.

The controller sees what it sees in evaluate (the delivered frame and the settings it was exposed with: the
observation, which the environment gives at the render size and in float64 for exactly this) and its command becomes
the action that sets exactly those settings (`ExposureEnv.action_of`), so driving it through the environment
reproduces evaluate's run of it byte for byte (tests/bench/test_env_matches_evaluate.py). Exact in `settings` mode
for any controller; in `ev_step` mode for exposure-first controllers whose steps stay within ±max_ev_step (AG+AE);
`absolute` mode refuses a command it cannot hit exactly (expoctl.bench.actions).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from expoctl.controllers.base import Controller, Settings


class ControllerPolicy:
    """`policy.reset(obs)` at each reset, then `action = policy(obs)` before each step."""

    def __init__(self, controller: Controller, env):
        base = getattr(env, "unwrapped", env)
        if base.obs_size is not None:
            raise ValueError("ControllerPolicy: the environment resizes its observations (obs_size); a controller "
                             "sees the frame at the render size, so build the environment without obs_size")
        self.controller, self.env = controller, base

    @staticmethod
    def settings(obs: dict[str, Any]) -> Settings:
        """The settings the observed frame was exposed with."""
        gain_db, exposure_us = (float(v) for v in obs["settings"])
        return Settings(gain_db, exposure_us)

    def reset(self, obs: dict[str, Any]) -> None:
        self.controller.reset(self.settings(obs))

    def __call__(self, obs: dict[str, Any]) -> np.ndarray:
        command = self.controller.update(obs["image"], self.settings(obs))
        return self.env.action_of(command)
