"""The reinforcement-learning baseline (docs/benchmark.md, "A reinforcement-learning baseline"): a stable-baselines3
agent (SAC or PPO) trained in `expoctl/Exposure-v0` on the training city only (`expoctl.bench.rl.train`), driven as the
`rl` controller (`expoctl.bench.rl.controller`). Needs the `rl` extra (stable-baselines3); nothing here imports it at
module level, so the registry loads without it."""

__all__ = []  # the modules are the interface: expoctl.bench.rl.config, .agent, .train, .controller
