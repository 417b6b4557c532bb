"""Environment speed: steps/s of expoctl/Exposure-v0 at the sizes an RL agent would train at.

Usage: .venv/bin/python benchmarks/env_speed.py [--steps 40] [--repeats 5] [--threads 2] [--split train]
Prints a table and writes benchmarks/results/env_speed.json.

The packaged default benchmark config (the real cities and textures, `world.render` replaced by each render size),
the training split, absolute actions drawn uniformly from the action space (a fresh, untrained agent's behaviour:
settings jump around, so the per-exposure caches rarely hit), the ORB reward only (`info_frontends` unset). Per
configuration: one untimed episode start and a few steps (numba kernels from the project's cache, the city's
texture atlas built), then `--repeats` times: a seeded reset (timed apart: it renders and plans the window) and
`--steps` steps; steps/s and ms per step are medians over the repeats. A step = set the settings, render the frame
at its exposure (motion blur), the sensor's capture, ORB on it and its match with the frame before (the reward), and
the observation's resize when `obs_size` is set. The load average is recorded: the machine is shared.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

_ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
_ap.add_argument("--steps", type=int, default=40, help="steps per repeat (default 40)")
_ap.add_argument("--repeats", type=int, default=5)
_ap.add_argument("--threads", type=int, default=2, help="numba threads (default 2)")
_ap.add_argument("--split", default="train")
_ap.add_argument("--out", type=Path,
                 default=Path(__file__).resolve().parents[1] / "benchmarks" / "results" / "env_speed.json")
ARGS = _ap.parse_args()
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"
os.environ["NUMBA_NUM_THREADS"] = str(ARGS.threads)

import time  # noqa: E402

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_meta import run_metadata  # noqa: E402
from expoctl.bench.env import ExposureEnv  # noqa: E402
from expoctl.io import write_json  # noqa: E402

#: (render size, observation size or None): the sizes an agent would train at, with and without a resize
CONFIGS = [((160, 120), None), ((160, 120), (80, 60)), ((320, 240), None), ((320, 240), (160, 120))]


def measure(render_size, obs_size, args) -> dict:
    env = ExposureEnv(args.split, render_size=render_size, obs_size=obs_size)
    rng = np.random.default_rng(0)

    def act():
        return rng.uniform(env.action_space.low, env.action_space.high)

    env.reset(seed=0)
    for _ in range(3):  # untimed: first renders of this size
        env.step(act())
    resets, rates, ms = [], [], []
    for r in range(args.repeats):
        t = time.perf_counter()
        env.reset(seed=r)
        resets.append(time.perf_counter() - t)
        n, t = 0, time.perf_counter()
        while n < args.steps:
            *_, terminated, _, _ = env.step(act())
            n += 1
            if terminated:  # a short window: go on in the next one (its reset not counted)
                t_reset = time.perf_counter()
                env.reset()
                t += time.perf_counter() - t_reset
        dt = time.perf_counter() - t
        rates.append(n / dt)
        ms.append(1e3 * dt / n)
    env.close()
    return {"render_size": list(render_size), "obs_size": list(obs_size) if obs_size else None,
            "steps_per_s": round(float(np.median(rates)), 2), "ms_per_step": round(float(np.median(ms)), 1),
            "ms_per_step_min": round(float(np.min(ms)), 1), "reset_s": round(float(np.median(resets)), 3),
            "steps_per_repeat": args.steps, "repeats": args.repeats}


def main() -> int:
    args = ARGS
    rows = [measure(render, obs, args) for render, obs in CONFIGS]
    load = os.getloadavg()
    result = {"split": args.split, "config": "packaged default", "action": "absolute, uniform random",
              "reward_frontend": "orb", "numba_threads": args.threads,
              "load_average_1_5_15min": [round(x, 2) for x in load], "rows": rows, **run_metadata()}
    print(f"expoctl/Exposure-v0 speed, split {args.split}, {args.repeats} repeats x {args.steps} steps, "
          f"{args.threads} numba thread(s), load avg {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} on {os.cpu_count()} cores")
    print(f"{'render':>9s} {'obs':>9s} {'steps/s':>8s} {'ms/step':>8s} {'min ms':>7s} {'reset s':>8s}")
    for r in rows:
        obs = "x".join(map(str, r["obs_size"])) if r["obs_size"] else "-"
        print(f"{'x'.join(map(str, r['render_size'])):>9s} {obs:>9s} {r['steps_per_s']:8.1f} {r['ms_per_step']:8.1f} "
              f"{r['ms_per_step_min']:7.1f} {r['reset_s']:8.2f}")
    write_json(result, args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
