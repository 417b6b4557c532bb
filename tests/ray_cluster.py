"""A real Ray cluster on 127.0.0.1 for the tests of the `ray` backend (expoctl.parallel): a head and n-1 more nodes,
each its own raylet with one CPU, started with the `ray` CLI of this environment, with Ray's token authentication on
(a fresh 256-bit token in the cluster's temporary directory: only a process given it can join or connect), and
stopped on exit, also when the test fails. Only this cluster's processes are stopped (found by its temporary
directory), never other Ray processes of the user (`ray stop --force` would stop them all)."""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

#: every process of the cluster and its driver: token authentication on (Ray 2.60 reads RAY_AUTH_MODE and the
#: token, RAY_AUTH_TOKEN or the file RAY_AUTH_TOKEN_PATH, at start; the path is set per cluster), one thread each
RAY_ENV = {"RAY_AUTH_MODE": "token", "RAY_USAGE_STATS_ENABLED": "0", "OMP_NUM_THREADS": "1",
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
    """Start the cluster; yield its address ('127.0.0.1:<port>'). The test process's environment gets RAY_ENV and
    the token's path meanwhile, so it connects as the cluster's owner."""
    import secrets

    token = temp_root / "auth_token"
    token.write_text(secrets.token_hex(32))  # what `ray get-auth-token --generate` writes to ~/.ray/auth_token
    token.chmod(0o600)
    cluster_env = {**RAY_ENV, "RAY_AUTH_TOKEN_PATH": str(token)}
    env = {**{k: v for k, v in os.environ.items() if k != "RAY_AUTH_TOKEN"}, **cluster_env}
    port = free_port()
    address = f"127.0.0.1:{port}"
    saved = {k: os.environ.get(k) for k in (*cluster_env, "RAY_AUTH_TOKEN")}
    os.environ.pop("RAY_AUTH_TOKEN", None)  # a token in the shell would win over the file
    os.environ.update(cluster_env)
    _refresh_ray_auth()
    common = ["--node-ip-address=127.0.0.1", f"--num-cpus={cpus_per_node}", "--num-gpus=0", "--disable-usage-stats",
              f"--object-store-memory={object_store_mb * 1024 * 1024}", f"--temp-dir={temp_root}"]
    try:
        head = _ray("start", "--head", f"--port={port}", "--include-dashboard=false", *common, env=env)
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
        stop_cluster(temp_root)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        _refresh_ray_auth()


def _refresh_ray_auth() -> None:
    """Make this (test) process see the authentication variables just set. Ray reads RAY_AUTH_MODE into its C++
    config and caches the token when `ray` is first imported, which in a test process is before the cluster exists
    (a stage process gets them from its shell, before any import, and needs nothing of this). Ray does the same
    itself when it turns token mode on (ray/_private/authentication/authentication_token_setup.py)."""
    from ray._raylet import AuthenticationTokenLoader, Config

    Config.initialize("")
    AuthenticationTokenLoader.instance().reset_cache()


def _cluster_pids(temp_root: Path) -> list[int]:
    """The processes of the cluster under `temp_root`: every Ray process names its session directory there."""
    mark = str(temp_root).encode()
    pids = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            if mark in (proc / "cmdline").read_bytes():
                pids.append(int(proc.name))
        except OSError:  # exited meanwhile, or not ours to read
            continue
    return pids


def stop_cluster(temp_root: Path, grace_s: float = 10.0) -> None:
    """Stop this cluster's processes only: SIGTERM, then SIGKILL for any still running after `grace_s`."""
    import signal

    for sig in (signal.SIGTERM, signal.SIGKILL):
        pids = _cluster_pids(temp_root)
        for pid in pids:
            try:
                os.kill(pid, sig)
            except OSError:
                pass
        deadline = time.monotonic() + grace_s
        while pids and time.monotonic() < deadline:
            time.sleep(0.2)
            pids = _cluster_pids(temp_root)
        if not pids:
            return
