"""What the benchmarks share: the machine and invocation metadata every benchmark's JSON records (the machines are
shared and noisy), and the resolved default config."""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path


def run_metadata() -> dict:
    """cpu_count, the host CPU (numba's target and the model name), 1-min load average at the time of writing, Python
    version and the command that produced it."""
    from expoctl.host import host_cpu  # the benchmarks put src/ on sys.path before importing this module

    script = Path(sys.argv[0])
    return {"cpu_count": os.cpu_count(), "host_cpu": host_cpu(), "load_average_1min": os.getloadavg()[0],
            "python": platform.python_version(), "command": " ".join([f"benchmarks/{script.name}", *sys.argv[1:]])}


def default_config(overrides: list[str] | None = None) -> dict:
    """The project's resolved config with `overrides`, composed as the compose stage does: the controllers'
    `${sensor.…}` and `${controllers.agae}` interpolations resolved (reading conf/*/default.yaml raw leaves them as
    strings, which the config readers refuse)."""
    root = Path(__file__).resolve().parents[1]
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    from stages.compose import compose_config

    return compose_config(list(overrides or []))
