"""A real Ray cluster on 127.0.0.1 for the tests of the `ray` backend (expoctl.parallel): a head and n-1 more nodes,
each its own raylet with one CPU, started with the `ray` CLI of this environment and stopped (`ray stop --force`)
on exit, also when the test fails."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

#: Ray 2.60 refuses a node joining without a token unless authentication is off (a private, local test cluster)
RAY_ENV = {"RAY_AUTH_MODE": "disabled", "RAY_USAGE_STATS_ENABLED": "0", "OMP_NUM_THREADS": "1",
           "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _ray(*args: str, env: dict) -> subprocess.CompletedProcess:
    exe = Path(sys.executable).with_name("ray")
    return subprocess.run([str(exe), *args], env=env, capture_output=True, text=True, timeout=180)


def _alive_nodes(address: str, env: dict) -> int:
    code = ("import ray; ray.init(address=%r, logging_level='ERROR'); "
            "print(sum(1 for n in ray.nodes() if n['Alive']))" % address)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    try:
        return int(out.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return 0


@contextlib.contextmanager
def local_ray_cluster(n_nodes: int, temp_root: Path, object_store_mb: int = 200,
                      cpus_per_node: int = 1) -> Iterator[str]:
    """Start the cluster; yield its address ('127.0.0.1:<port>'). The test process's environment gets RAY_ENV
    meanwhile (the driver must not ask for a token either)."""
    env = {**os.environ, **RAY_ENV}
    port = free_port()
    address = f"127.0.0.1:{port}"
    saved = {k: os.environ.get(k) for k in RAY_ENV}
    os.environ.update(RAY_ENV)
    common = ["--node-ip-address=127.0.0.1", f"--num-cpus={cpus_per_node}", "--num-gpus=0", "--disable-usage-stats",
              f"--object-store-memory={object_store_mb * 1024 * 1024}"]
    try:
        head = _ray("start", "--head", f"--port={port}", "--include-dashboard=false",
                    f"--temp-dir={temp_root}", *common, env=env)
        if head.returncode != 0:
            raise RuntimeError(f"ray start --head failed:\n{head.stdout}\n{head.stderr}")
        for _ in range(n_nodes - 1):
            node = _ray("start", f"--address={address}", *common, env=env)
            if node.returncode != 0:
                raise RuntimeError(f"ray start --address={address} failed:\n{node.stdout}\n{node.stderr}")
        deadline = time.monotonic() + 60
        while (alive := _alive_nodes(address, env)) < n_nodes:
            if time.monotonic() > deadline:
                raise RuntimeError(f"Ray cluster at {address}: {alive} of {n_nodes} nodes alive after 60 s")
            time.sleep(1.0)
        yield address
    finally:
        from expoctl.parallel import disconnect_ray

        disconnect_ray()
        _ray("stop", "--force", env=env)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
