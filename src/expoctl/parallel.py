"""One fan-out layer for the stages that run independent jobs: collect (one sequence each), features (one sequence
each), evaluate and model selection (one run each), the saturation probe (one candidate each).

`run_ordered(fn, items, parallel=parallel)` calls the module-level function `fn` on every item and yields
`(item, fn(item))` in the order of `items`, whatever the backend and whatever order the jobs finish in, so the
results — and every byte a caller writes from them — do not depend on where the work ran. Backends
(`ParallelConfig`, config group `parallel`):

- `inprocess`: a plain loop in this process (also what `processes` does for one job or n_jobs == 1);
- `processes`: `parallel.n_jobs` spawned worker processes on this host, one BLAS/OpenMP/numba thread each
  (`expoctl.host.single_threaded_children`); spawn, not fork: workers may load torch or OpenCV, whose threads make a
  forked child hang on a lock they held;
- `ray`: the tasks go to an existing Ray cluster (`ray.init(address=…)`; `ray` is an optional extra), one CPU and one
  thread per task; the cluster's CPUs, not n_jobs, bound how many run at once. Workers import this project through
  the job's `runtime_env` (the `expoctl` package is uploaded); its dependencies must be installed on every node, and
  paths the jobs read or write (raw sequences, images) must be visible to every node (one host or a shared file
  system).

Jobs get typed, picklable inputs (frozen dataclasses) and build their own detectors, matchers and controllers; no
experiment tracking happens in a worker. A worker can send text lines back while it runs (`messages`: collect's
per-sequence progress), and `progress(item, result)` is called in this process as each job finishes.
"""

from __future__ import annotations

import os
import queue as queue_module
import socket
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, replace
from multiprocessing import get_context
from typing import Any, TypeVar

from expoctl.config_reader import Problems, Section, is_integer
from expoctl.errors import ConfigError

T = TypeVar("T")
R = TypeVar("R")

BACKENDS = ("inprocess", "processes", "ray")
#: the environment every worker (process or Ray task) runs with: one thread per library, so n workers use n cores
SINGLE_THREAD_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                     "NUMBA_NUM_THREADS": "1"}
#: why a stage group's old `n_jobs` key is refused: the worker count is `parallel.n_jobs` now, a runtime setting
MOVED_N_JOBS = "one worker count for every stage, not a stage param; changed 2026-12-07, docs/scale_out.md"
#: seconds allowed for the TCP connection to a Ray cluster's address before it is called unreachable
CONNECT_TIMEOUT_S = 5.0
_POLL_S = 0.5  # how often waiting for jobs also forwards worker messages


def _bad_jobs(n_jobs: Any) -> str | None:
    """What is wrong with a worker count (None: nothing)."""
    if is_integer(n_jobs) and (n_jobs >= 1 or n_jobs == -1):
        return None
    return f"must be a positive integer or -1 (one worker per core), got {n_jobs!r}"


@dataclass(frozen=True)
class ParallelConfig:
    """Config group `parallel` (conf/parallel/default.yaml): where the jobs run. It never changes a result."""

    backend: str = "processes"
    address: str | None = None  # ray: the cluster's address, host:port of its head (`ray start --head --port`)
    #: processes: worker processes on this host per stage (-1: one per core; 1: the jobs run in this process). The
    #: ray backend ignores it (the cluster's CPUs bound the jobs at once). Never changes a result.
    n_jobs: int = 1

    @classmethod
    def from_dict(cls, d: Any, key: str = "parallel", problems: Problems | None = None) -> "ParallelConfig":
        r = Section(d, key, problems)
        backend = r.choice("backend", BACKENDS, "processes")
        address = r.text("address", None, nullable=True)
        if backend == "ray" and not address:
            r.problem("address", "missing: the ray backend connects to an existing cluster (host:port of its head, "
                                 "or 'auto' on a node of the cluster)")
        n_jobs = r.value("n_jobs", 1)
        if _bad_jobs(n_jobs):
            r.problem("n_jobs", _bad_jobs(n_jobs))
            n_jobs = 1
        r.done()
        return cls(backend or "processes", address, int(n_jobs))

    @property
    def workers(self) -> int:
        """n_jobs with -1 resolved to this host's cores."""
        return (os.cpu_count() or 1) if self.n_jobs == -1 else self.n_jobs

    def with_jobs(self, n_jobs: int | None) -> "ParallelConfig":
        """The same backend with another worker count (None: unchanged); ConfigError naming `parallel.n_jobs` for a
        bad one."""
        if n_jobs is None:
            return self
        if _bad_jobs(n_jobs):
            raise ConfigError("parallel.n_jobs", _bad_jobs(n_jobs))
        return replace(self, n_jobs=int(n_jobs))

    @classmethod
    def from_resolved(cls, cfg: Any, problems: Problems | None = None) -> "ParallelConfig":
        """From the resolved config's `parallel` block (absent: the default, worker processes on this host)."""
        top = cfg if isinstance(cfg, dict) else {}
        return cls.from_dict(top.get("parallel"), "parallel", problems)


INPROCESS = ParallelConfig("inprocess")


def run_ordered(fn: Callable[..., R], items: Sequence[T], n_jobs: int | None = None,
                parallel: ParallelConfig | None = None, *,
                progress: Callable[[T, R], None] | None = None, messages: Callable[[str], None] | None = None,
                initializer: Callable[[], None] | None = None, start_method: str = "spawn",
                preload: Sequence[str] = ()) -> Iterator[tuple[T, R]]:
    """(item, fn(item)) for every item, in the order of `items`.

    fn: a module-level function (workers import it by name); with `messages` it is called as fn(item, emit) and every
    emit(line) reaches `messages(line)` in this process (from workers while they run; at the latest when the job
    ends). progress(item, result): called here as each job finishes, in completion order. initializer: run in each
    worker before its jobs (processes: once per process; ray: before every task, so it must be idempotent; in
    process: never — it sets worker-only state). start_method: the processes backend's, spawn or forkserver (never
    fork, see the module docstring); `preload`: modules the fork server imports once, so its workers start in
    milliseconds (forkserver only; spawn where the OS lacks it). A job's exception is raised here (its own type,
    e.g. InputError); the jobs not yet started are cancelled. n_jobs: the worker processes (None: `parallel`'s)."""
    parallel = parallel or ParallelConfig()
    n_jobs = parallel.workers if n_jobs is None else n_jobs
    items = list(items)
    if parallel.backend == "ray" and items:
        yield from _run_ray(fn, items, parallel.address, progress, messages, initializer)
    elif parallel.backend == "inprocess" or n_jobs <= 1 or len(items) <= 1:
        yield from _run_here(fn, items, progress, messages)
    else:
        yield from _run_processes(fn, items, n_jobs, progress, messages, initializer, _context(start_method, preload))


# ---------------------------------------------------------------------------------------------------- in process


def _run_here(fn, items, progress, messages) -> Iterator[tuple[Any, Any]]:
    for item in items:
        result = fn(item) if messages is None else fn(item, messages)
        if progress is not None:
            progress(item, result)
        yield item, result


# ----------------------------------------------------------------------------------------------------- processes

_WORKER_QUEUE = None  # a worker process's channel for message lines (set by `_init_process`)


def _init_process(queue, initializer) -> None:
    global _WORKER_QUEUE
    _WORKER_QUEUE = queue
    if initializer is not None:
        initializer()


def _call_in_process(fn, item):
    return fn(item) if _WORKER_QUEUE is None else fn(item, _WORKER_QUEUE.put)


def _drain(q, messages) -> None:
    if q is None:
        return
    while True:
        try:
            line = q.get_nowait()
        except queue_module.Empty:
            return
        messages(line)


def _context(start_method: str, preload: Sequence[str]):
    import multiprocessing

    if start_method not in ("spawn", "forkserver"):
        raise ValueError(f"start_method must be spawn or forkserver, got {start_method!r}")
    if start_method == "forkserver" and "forkserver" in multiprocessing.get_all_start_methods():
        ctx = get_context("forkserver")
        if preload:
            ctx.set_forkserver_preload(list(preload))
        return ctx
    return get_context("spawn")


def _run_processes(fn, items, n_jobs, progress, messages, initializer, ctx) -> Iterator[tuple[Any, Any]]:
    from expoctl.host import single_threaded_children

    q = ctx.Queue() if messages is not None else None
    results: dict[int, Any] = {}
    next_out = 0
    with single_threaded_children(), ProcessPoolExecutor(max_workers=min(n_jobs, len(items)), mp_context=ctx,
                                                         initializer=_init_process, initargs=(q, initializer)) as pool:
        futures = {pool.submit(_call_in_process, fn, item): i for i, item in enumerate(items)}
        try:
            pending = set(futures)
            while pending:
                done, pending = wait(pending, timeout=_POLL_S, return_when=FIRST_COMPLETED)
                _drain(q, messages)
                for fut in sorted(done, key=futures.__getitem__):
                    i = futures[fut]
                    results[i] = fut.result()  # a worker's exception is raised here
                    if progress is not None:
                        progress(items[i], results[i])
                while next_out in results:
                    yield items[next_out], results.pop(next_out)
                    next_out += 1
        except BaseException:
            pool.shutdown(wait=True, cancel_futures=True)
            raise
    _drain(q, messages)  # the workers have exited: every line they put is in the queue now
    while next_out in results:
        yield items[next_out], results.pop(next_out)
        next_out += 1


# ----------------------------------------------------------------------------------------------------------- ray

_RAY_ADDRESS: str | None = None  # the cluster this process is connected to
_RAY_LOCK = threading.Lock()


def import_ray():
    """The ray module, or a ConfigError saying how to install it."""
    try:
        import ray
    except ImportError:
        raise ConfigError("parallel.backend", "is ray, but ray is not installed in this environment "
                                              "(pip install -e '.[ray]')") from None
    return ray


def check_reachable(address: str, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
    """ConfigError naming `address` when nothing accepts a TCP connection there ('auto' and ray:// are left to Ray)."""
    if address == "auto" or "://" in address:
        return
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit() or not host:
        raise ConfigError("parallel.address", f"{address!r} is not host:port (the Ray head's GCS address)")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except OSError as exc:
        raise ConfigError("parallel.address", f"no Ray cluster reachable at {address} ({exc}); start one with "
                                              f"`ray start --head --port {port}` or fix the address") from None


def runtime_env(upload_code: bool | None = None) -> dict:
    """The Ray job's runtime environment: the pinned numeric mode if this process runs in it, one thread per library
    in every worker and, with `upload_code` (default:
    the environment variable EXPOCTL_RAY_UPLOAD_CODE=1), the expoctl package uploaded so workers import this
    checkout's code. Off by default: on nodes that have the project installed (one host, a shared venv) the upload
    only costs time — numba's on-disk cache is keyed by the source file's path, so an uploaded copy compiles every
    kernel again in every worker (measured: a 6-frame collect sequence took 105 s instead of 3 s)."""
    if upload_code is None:
        upload_code = os.environ.get("EXPOCTL_RAY_UPLOAD_CODE", "0") == "1"
    from expoctl.numerics import forwarded_env

    # A Ray worker does not inherit this process's environment (it may be another node's process): the numeric mode
    # this stage runs in (expoctl.numerics: read at import, so it must be in the worker's environment at start; Ray
    # starts a separate worker pool per env_vars) goes with every task, and then one thread per library.
    env: dict = {"env_vars": {**forwarded_env(), **SINGLE_THREAD_ENV}}
    if upload_code:
        import expoctl

        env.update(py_modules=[expoctl], excludes=["__pycache__", "*.pyc"])
    return env


def connect_ray(address: str):
    """Connect this process to the Ray cluster at `address` (once; again if the address changed); the ray module."""
    global _RAY_ADDRESS
    ray = import_ray()
    with _RAY_LOCK:
        if ray.is_initialized() and _RAY_ADDRESS == address:
            return ray
        if ray.is_initialized():
            ray.shutdown()
        check_reachable(address)
        try:
            ray.init(address=address, runtime_env=runtime_env(), log_to_driver=False, logging_level="WARNING",
                     configure_logging=False)
        except (ConnectionError, TimeoutError, RuntimeError, ray.exceptions.AuthenticationError) as exc:
            # a cluster with token authentication answers a client without its token with "Unauthenticated" in
            # Ray's log and a plain ConnectionError here (ray 2.60): say what to check
            hint = ("" if os.environ.get("RAY_AUTH_MODE", "").lower() == "token" else
                    "; if the cluster uses token authentication, this process needs RAY_AUTH_MODE=token and the "
                    "cluster's token (RAY_AUTH_TOKEN, or the file RAY_AUTH_TOKEN_PATH, default ~/.ray/auth_token; "
                    "docs/scale_out.md)")
            raise ConfigError("parallel.address",
                              f"could not connect to the Ray cluster at {address}: {exc}{hint}") from None
        _RAY_ADDRESS = address
    return ray


def disconnect_ray() -> None:
    """Leave the Ray cluster (the cluster keeps running)."""
    global _RAY_ADDRESS
    try:
        import ray
    except ImportError:
        return
    with _RAY_LOCK:
        if ray.is_initialized():
            ray.shutdown()
        _RAY_ADDRESS = None


def _call_in_ray(fn, item, q, initializer):
    """A Ray task: fn on one item (messages through the Ray queue actor `q`)."""
    if initializer is not None:
        initializer()
    return fn(item) if q is None else fn(item, q.put)


def _run_ray(fn, items, address, progress, messages, initializer) -> Iterator[tuple[Any, Any]]:
    ray = connect_ray(address)
    remote = ray.remote(num_cpus=1, max_retries=0)(_call_in_ray)
    q = None
    if messages is not None:
        from ray.util.queue import Queue

        q = Queue(actor_options={"num_cpus": 0})
    refs = [remote.remote(fn, item, q, initializer) for item in items]
    index = {ref: i for i, ref in enumerate(refs)}
    results: dict[int, Any] = {}
    next_out = 0
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1, timeout=_POLL_S)
            _drain_ray(q, messages)
            for ref in done:
                i = index[ref]
                results[i] = _ray_get(ray, ref)
                if progress is not None:
                    progress(items[i], results[i])
            while next_out in results:
                yield items[next_out], results.pop(next_out)
                next_out += 1
        _drain_ray(q, messages)
    except BaseException:
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    finally:
        if q is not None:
            q.shutdown()


def _ray_get(ray, ref):
    """ray.get, raising a task's own exception (InputError stays InputError, with its message) instead of Ray's
    wrapper."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        cause = getattr(exc, "cause", None)
        if isinstance(cause, BaseException):
            raise cause from None
        raise


def _drain_ray(q, messages) -> None:
    if q is None:
        return
    for line in q.get_nowait_batch(q.qsize()) if q.qsize() else []:
        messages(line)


def collect_all(fn: Callable[..., R], items: Iterable[T], n_jobs: int | None = None,
                parallel: ParallelConfig | None = None,
                **kwargs) -> list[R]:
    """`fn(item)` for every item, in order (`run_ordered`'s results only)."""
    return [r for _, r in run_ordered(fn, list(items), n_jobs, parallel, **kwargs)]
