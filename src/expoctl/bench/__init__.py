"""The public closed-loop benchmark: a gymnasium environment, `expoctl bench` and its leaderboard (docs/benchmark.md)."""

from expoctl.bench.registration import ENV_ID, register_envs

register_envs()  # gymnasium.make("expoctl.bench:expoctl/Exposure-v0") imports this package for the id

__all__ = ["ENV_ID", "register_envs"]
