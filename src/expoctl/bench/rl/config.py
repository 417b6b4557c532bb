"""`rl`: the typed config of the reinforcement-learning baseline (conf/rl/default.yaml), read by the train_rl stage."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from expoctl.config_reader import param, read_config

ALGORITHMS = ("sac", "ppo")
#: the environment's action modes an agent may train in (`settings` is for replaying controllers, not learning)
AGENT_ACTIONS = ("ev_step", "absolute")


def _size(r, name, default, nullable=False):
    """A (width, height) pair of whole pixels (with `nullable`, null too: no resize)."""
    value = r.value(name, default)
    if value is None and nullable:
        return None
    if not (isinstance(value, (list, tuple)) and len(value) == 2 and all(
            isinstance(v, int) and not isinstance(v, bool) and 16 <= v <= 8192 for v in value)):
        r.problem(name, f"must be [width, height] in whole pixels (16–8192){' or null' if nullable else ''}, "
                        f"got {value!r}")
        return default
    return (int(value[0]), int(value[1]))


@dataclass(frozen=True)
class RLConfig:
    """Training: `total_steps` env steps of `algorithm` on `ExposureEnv(split="train")` built with the env keys
    below; a checkpoint every `checkpoint_every` steps; a second run with a larger total_steps continues."""

    enabled: bool = False                     # off: the train_rl stage writes a marker, evaluate skips `rl`
    algorithm: str = param("sac", choices=ALGORITHMS)
    total_steps: int = param(20000, min=1)
    seed: int = param(0, min=0)
    # the environment (expoctl.bench.env.ExposureEnv's arguments)
    render_size: tuple[int, ...] = param((160, 120), read=_size)
    obs_size: tuple[int, ...] | None = param((80, 60), read=lambda r, n, d: _size(r, n, d, nullable=True))
    action: str = param("ev_step", choices=AGENT_ACTIONS)
    exposure_scale: str = param("log", choices=("log", "linear"))
    max_ev_step: float = param(1.0, above=0.0, max=20.0, unit="EV")
    frontend: str = "orb"
    reward_scale: float = param(0.01, above=0.0)
    clipped_penalty: float = param(0.0, min=0.0)
    train_traversals: int = param(64, min=1)
    # the agent's input: a grey-level histogram of the observation with this many bins, plus its settings
    histogram_bins: int = param(32, min=4, max=256)
    # the learner
    learning_rate: float = param(3e-4, above=0.0, max=1.0)
    buffer_size: int = param(50000, min=100)          # SAC's replay buffer (transitions)
    learning_starts: int = param(500, min=0)          # SAC: random actions before the first update
    batch_size: int = param(256, min=8)
    gamma: float = param(0.9, above=0.0, max=1.0)     # short horizon: a setting matters for the next few frames
    n_steps: int = param(512, min=8)                  # PPO: rollout length
    net_arch: tuple[int, ...] = param((64, 64), min=1, length=None)
    torch_threads: int = param(1, min=1)              # leaves the cores to the simulator
    checkpoint_every: int = param(2000, min=1)
    log_every: int = param(100, min=1)                # MLflow metrics every this many steps

    def check(self, r) -> None:
        from expoctl.features.registry import FRONTENDS

        if self.frontend not in FRONTENDS.names():
            r.problem("frontend", f"unknown front end {self.frontend!r} (registered: {', '.join(FRONTENDS.names())})")
        if self.obs_size is not None and (self.obs_size[0] > self.render_size[0]
                                          or self.obs_size[1] > self.render_size[1]):
            r.problem("obs_size", f"{list(self.obs_size)} must fit in render_size {list(self.render_size)} "
                                  "(a downscale)")
        if self.algorithm == "sac" and self.batch_size > self.buffer_size:
            r.problem("batch_size", f"{self.batch_size} exceeds buffer_size {self.buffer_size}")

    def env_kwargs(self) -> dict:
        """The environment's construction arguments (besides split and config)."""
        return {"render_size": tuple(self.render_size), "obs_size": None if self.obs_size is None
                else tuple(self.obs_size), "action": self.action, "exposure_scale": self.exposure_scale,
                "max_ev_step": self.max_ev_step, "frontend": self.frontend, "reward_scale": self.reward_scale,
                "clipped_penalty": self.clipped_penalty, "train_traversals": self.train_traversals}

    def as_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}


def read_rl_config(section, problems=None) -> RLConfig:
    return read_config(RLConfig, section, "rl", problems)
