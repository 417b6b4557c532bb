"""The public closed-loop benchmark: a gymnasium environment, `expoctl bench` and its leaderboard (docs/benchmark.md)."""
