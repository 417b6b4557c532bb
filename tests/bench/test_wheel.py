"""The environment from a built wheel, installed outside the checkout: no conf/, no checkout on sys.path, the
packaged config and cities only (issue 45: "it works from a wheel installed outside the checkout").

numba: a fresh install compiles the render, sensor and matcher kernels on first use, which took over 10 minutes on
the shared 2-core machine. numba 0.68 keys its cache by the source file's content hash, not its path or mtime, so the
test first makes sure this checkout's cache holds every kernel an episode needs (one episode step in this process)
and copies those cache files into the installed package's __pycache__: the wheel's own code runs, without paying
the compile again (as a user's second run would)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

#: run with -I (no PYTHONPATH, no cwd, no user site); the venv's site-packages supply the dependencies, but its
#: editable install of expoctl (a .pth entry for the checkout's src/) is dropped, so only the wheel's copy is found
SCRIPT = r"""
import json, os, sys
target, checkout = sys.argv[1], sys.argv[2]
drop = (checkout, os.path.join(checkout, "src"))  # the checkout's root and the editable install's src/
sys.path[:] = [target] + [p for p in sys.path if os.path.realpath(p) not in drop]
import gymnasium as gym
env = gym.make("expoctl.bench:expoctl/Exposure-v0", split="test", scale="fixture", obs_size=(80, 60))
obs, info = env.reset(seed=0)
rewards = [env.step(env.action_space.sample())[1] for _ in range(3)]
import expoctl
print(json.dumps({"expoctl": expoctl.__file__, "modules": sorted({os.path.realpath(getattr(m, "__file__", None) or "")
      for n, m in sys.modules.items() if n.split(".")[0] in ("expoctl", "stages")}),
      "shape": list(obs["image"].shape), "rewards": rewards, "sequence": info["sequence"]}))
"""


def _seed_numba_cache(target: Path) -> int:
    """Copy this checkout's numba cache files beside the installed modules; how many were copied."""
    from expoctl.bench.env import ExposureEnv

    env = ExposureEnv("test", scale="fixture", obs_size=(80, 60))  # compiles into the checkout's cache if needed
    env.reset(seed=0)
    env.step(env.action_space.sample())
    n = 0
    for cached in (REPO / "src" / "expoctl").rglob("__pycache__/*.nb[ic]"):
        dest = target / "expoctl" / cached.relative_to(REPO / "src" / "expoctl")
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(cached, dest)
        n += 1
    return n


def test_env_runs_from_a_wheel_outside_the_checkout(tmp_path):
    # build from a copy of the sources, so the shared checkout gets no build/ or egg-info from the test
    src = tmp_path / "src_copy"
    shutil.copytree(REPO / "src" / "expoctl", src / "src" / "expoctl",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.nbi", "*.nbc"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    wheels, target, work = tmp_path / "wheels", tmp_path / "site", tmp_path / "work"
    work.mkdir()
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "-q"]
    subprocess.run(pip + ["wheel", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(src)], check=True,
                   cwd=work)
    [wheel] = wheels.glob("expoctl-*.whl")
    subprocess.run(pip + ["install", "--no-deps", "--target", str(target), str(wheel)], check=True, cwd=work)
    assert (target / "expoctl" / "bench" / "configs" / "fixture.yaml").is_file()  # package data shipped
    assert _seed_numba_cache(target) > 0
    # no NUMBA_CACHE_DIR: numba looks in the installed package's own __pycache__
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "NUMBA_CACHE_DIR")}
    out = subprocess.run([sys.executable, "-I", "-c", SCRIPT, str(target), str(REPO.resolve())], cwd=work, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert Path(result["expoctl"]).resolve().is_relative_to(target.resolve())
    assert result["modules"] and all(Path(m).is_relative_to(target.resolve()) for m in result["modules"])
    assert result["shape"] == [60, 80, 3] and len(result["rewards"]) == 3
    assert result["sequence"].startswith("test-")
