"""Machine and invocation metadata that every benchmark's JSON records (the machines are shared and noisy)."""

from __future__ import annotations

import os
import platform
import sys
from pathlib import Path


def run_metadata() -> dict:
    """cpu_count, 1-min load average at the time of writing, Python version and the command that produced it."""
    script = Path(sys.argv[0])
    return {"cpu_count": os.cpu_count(), "load_average_1min": os.getloadavg()[0], "python": platform.python_version(),
            "command": " ".join([f"benchmarks/{script.name}", *sys.argv[1:]])}
