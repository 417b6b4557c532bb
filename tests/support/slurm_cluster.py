"""A real single-node SLURM cluster for tests: slurmctld + slurmd (+ munged) bound to 127.0.0.1, every file in a
fresh directory under /tmp, started by tests/support/slurm/start_cluster.sh and torn down by stop_cluster.sh
(nothing left running). Needs root and Debian's slurmctld slurmd slurm-client munge; .ci/run installs them and sets
EXPOCTL_REQUIRE_SLURM_TESTS=1, so in CI a missing piece fails the test instead of skipping it."""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

SCRIPTS = Path(__file__).resolve().parent / "slurm"
NEEDED = ("slurmctld", "slurmd", "sbatch", "squeue", "scontrol", "munged")


def missing() -> list[str]:
    """What keeps a private cluster from starting here (empty: nothing)."""
    out = [b for b in NEEDED if shutil.which(b) is None]
    if os.geteuid() != 0:
        out.append("root (slurmd runs jobs as their user)")
    return out


@contextmanager
def slurm_cluster() -> Iterator[dict[str, str]]:
    """Start a cluster; yields the environment a client needs (SLURM_CONF, and PATH with the `sacct` stand-in
    submitit polls, since the cluster keeps no accounting); stops it afterwards."""
    lacking = missing()
    if lacking:
        msg = f"a private SLURM cluster needs {', '.join(lacking)} (apt-get install slurmctld slurmd slurm-client munge)"
        if os.environ.get("EXPOCTL_REQUIRE_SLURM_TESTS") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    # a short path: munge's unix socket path must stay under 108 bytes
    d = Path(tempfile.mkdtemp(prefix="slurm-", dir="/tmp"))
    p = subprocess.run([str(SCRIPTS / "start_cluster.sh"), str(d)], text=True, capture_output=True, timeout=120)
    if p.returncode != 0:
        pytest.fail(f"the SLURM cluster did not start:\n{p.stderr[-3000:]}")
    started = dict(line.split("=", 1) for line in p.stdout.splitlines() if "=" in line)
    env = {"SLURM_CONF": started["SLURM_CONF"],
           "PATH": started["TEST_SLURM_BIN"] + os.pathsep + os.environ.get("PATH", "")}
    try:
        yield env
    finally:
        stop = subprocess.run([str(SCRIPTS / "stop_cluster.sh"), str(d)], text=True, capture_output=True, timeout=120)
        shutil.rmtree(d, ignore_errors=True)
        assert stop.returncode == 0, f"SLURM cluster processes left running:\n{stop.stderr[-2000:]}"
