"""expoctl.parallel: results in input order and identical whatever the backend; config errors named by key."""

from __future__ import annotations

import sys
import time

import pytest

from expoctl.errors import ConfigError, InputError
from expoctl.parallel import (INPROCESS, ParallelConfig, check_reachable, collect_all, connect_ray, run_ordered)
from ray_cluster import free_port

ITEMS = list(range(6))


def slow_square(x: int) -> tuple[int, int]:
    """Later items finish first (the first sleeps longest), and the worker's pid rides along."""
    import os

    time.sleep(0.05 * (len(ITEMS) - x))
    return x * x, os.getpid()


def square(x: int) -> int:
    return slow_square(x)[0]


def chatty(x: int, emit) -> int:
    for k in range(3):
        emit(f"{x}:{k}")
    return -x


def fails_on_three(x: int) -> int:
    if x == 3:
        raise InputError("item 3 is bad")
    return x


# ------------------------------------------------------------------------------------------------------- config


def test_config_defaults_and_reading():
    assert ParallelConfig.from_dict(None) == ParallelConfig("processes", None)
    assert ParallelConfig.from_resolved({}) == ParallelConfig()
    assert ParallelConfig.from_dict({"backend": "ray", "address": "10.0.0.1:6379"}).address == "10.0.0.1:6379"
    assert ParallelConfig.from_resolved({"parallel": {"backend": "inprocess", "address": None}}) == INPROCESS
    assert ParallelConfig().n_jobs == 1 and ParallelConfig.from_dict({"n_jobs": 3}).workers == 3
    import os

    assert ParallelConfig.from_dict({"n_jobs": -1}).workers == (os.cpu_count() or 1)


def test_with_jobs_overrides_the_worker_count_and_checks_it():
    base = ParallelConfig("processes", n_jobs=2)
    assert base.with_jobs(None) is base and base.with_jobs(4) == ParallelConfig("processes", None, 4)
    with pytest.raises(ConfigError) as e:
        base.with_jobs(0)
    assert e.value.key == "parallel.n_jobs"


def test_the_worker_count_comes_from_the_config_when_not_given():
    """run_ordered without n_jobs uses parallel.n_jobs: 1 runs here, 2 in worker processes."""
    import os

    assert {r[1] for r in collect_all(slow_square, ITEMS[:2], parallel=ParallelConfig(n_jobs=1))} == {os.getpid()}
    assert os.getpid() not in {r[1] for r in collect_all(slow_square, ITEMS[:2], parallel=ParallelConfig(n_jobs=2))}


@pytest.mark.parametrize("d, key, problem", [
    ({"backend": "dask"}, "parallel.backend", "must be one of inprocess, processes, ray, got 'dask'"),
    ({"backend": "ray"}, "parallel.address", "missing: the ray backend connects to an existing cluster"),
    ({"backend": "ray", "address": 6379}, "parallel.address", "must be a non-empty string or null, got 6379"),
    ({"workers": 3}, "parallel.workers", "unknown key"),
    ({"n_jobs": 0}, "parallel.n_jobs", "must be a positive integer or -1 (one worker per core), got 0"),
    ({"n_jobs": 1.5}, "parallel.n_jobs", "must be a positive integer or -1 (one worker per core), got 1.5"),
])
def test_bad_config_names_the_full_key(d, key, problem):
    with pytest.raises(ConfigError) as e:
        ParallelConfig.from_dict(d)
    assert e.value.key == key and e.value.problem.startswith(problem)


# -------------------------------------------------------------------------------------------- local backends


@pytest.mark.parametrize("backend", ["inprocess", "processes"])
def test_results_in_input_order_whatever_finishes_first(backend):
    done = []
    out = list(run_ordered(slow_square, ITEMS, 3, ParallelConfig(backend), progress=lambda i, r: done.append(i)))
    assert [item for item, _ in out] == ITEMS
    assert [r[0] for _, r in out] == [x * x for x in ITEMS]
    assert sorted(done) == ITEMS
    pids = {r[1] for _, r in out}
    import os

    if backend == "inprocess":
        assert pids == {os.getpid()} and done == ITEMS
    else:  # in workers, and the short late jobs finished before the long first one
        assert os.getpid() not in pids and done != ITEMS


def test_one_job_or_one_worker_runs_here():
    import os

    assert collect_all(slow_square, [2], 4)[0][1] == os.getpid()
    assert {r[1] for r in collect_all(slow_square, ITEMS[:2], 1)} == {os.getpid()}


@pytest.mark.parametrize("backend", ["inprocess", "processes"])
def test_worker_messages_reach_the_caller(backend):
    lines: list[str] = []
    out = collect_all(chatty, ITEMS, 2, ParallelConfig(backend), messages=lines.append)
    assert out == [-x for x in ITEMS]
    assert sorted(lines) == sorted(f"{x}:{k}" for x in ITEMS for k in range(3))
    for x in ITEMS:  # each job's own lines stay in order
        assert [line for line in lines if line.startswith(f"{x}:")] == [f"{x}:{k}" for k in range(3)]


@pytest.mark.parametrize("backend", ["inprocess", "processes"])
def test_a_jobs_error_keeps_its_type_and_message(backend):
    with pytest.raises(InputError, match="item 3 is bad"):
        collect_all(fails_on_three, ITEMS, 2, ParallelConfig(backend))


# ------------------------------------------------------------------------------------------------------ ray


def test_ray_missing_is_a_config_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray → ImportError
    with pytest.raises(ConfigError) as e:
        connect_ray("127.0.0.1:6379")
    assert e.value.key == "parallel.backend" and "pip install -e '.[ray]'" in e.value.problem


def test_unreachable_address_is_named_quickly():
    port = free_port()  # nothing listens there
    t0 = time.perf_counter()
    with pytest.raises(ConfigError) as e:
        check_reachable(f"127.0.0.1:{port}", timeout_s=2.0)
    assert e.value.key == "parallel.address" and f"127.0.0.1:{port}" in e.value.problem
    assert time.perf_counter() - t0 < 3.0
    with pytest.raises(ConfigError, match="is not host:port"):
        check_reachable("headnode")


def test_ray_backend_with_an_unreachable_cluster_names_the_address():
    pytest.importorskip("ray")  # CI installs the ray extra; without it this is test_ray_missing_is_a_config_error
    port = free_port()
    with pytest.raises(ConfigError, match=f"no Ray cluster reachable at 127.0.0.1:{port}"):
        collect_all(square, ITEMS, 2, ParallelConfig("ray", f"127.0.0.1:{port}"))


@pytest.fixture(scope="module")
def ray_address(tmp_path_factory):
    ray = pytest.importorskip("ray")
    cloudpickle = ray.cloudpickle  # Ray's own copy pickles the tasks' arguments

    from ray_cluster import local_ray_cluster

    # this test module is not importable on the Ray workers: ship its functions by value
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    with local_ray_cluster(1, tmp_path_factory.mktemp("ray")) as address:
        yield address
    cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


@pytest.mark.slow  # starts a one-node Ray cluster (~10 s)
def test_ray_backend_gives_the_same_results_in_order_with_messages_and_errors(ray_address):
    ray_cfg = ParallelConfig("ray", ray_address)
    done = []
    out = list(run_ordered(slow_square, ITEMS, 1, ray_cfg, progress=lambda i, r: done.append(i)))
    assert [(item, r[0]) for item, r in out] == [(x, x * x) for x in ITEMS] and sorted(done) == ITEMS
    lines: list[str] = []
    assert collect_all(chatty, ITEMS, 1, ray_cfg, messages=lines.append) == [-x for x in ITEMS]
    assert sorted(lines) == sorted(f"{x}:{k}" for x in ITEMS for k in range(3))
    with pytest.raises(InputError, match="item 3 is bad"):
        collect_all(fails_on_three, ITEMS, 1, ray_cfg)
