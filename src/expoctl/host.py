"""Which CPU a run used, recorded so that two runs of one commit can be told apart by their host.

Same-commit runs are byte-identical on one machine (docs/runs/old_camera_results.md), but numba compiles every kernel for the
host CPU (instruction set, FMA contraction) and numpy and OpenCV choose SIMD kernels at run time, so the last bit of
a float — and, through training, a network — can move between machines. The numba target name is the part that
decides its code generation; the model name is for people.
"""

from __future__ import annotations

import contextlib
import os
import platform
from collections.abc import Iterator
from pathlib import Path


def cpu_model_name(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The CPU's marketing name ('model name' in /proc/cpuinfo on Linux), else platform.processor(), else 'unknown'."""
    try:
        for line in cpuinfo.read_text(errors="replace").splitlines():
            key, sep, value = line.partition(":")
            if sep and key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def numba_target_cpu() -> str:
    """The CPU name LLVM (numba's back end) generates code for on this host, e.g. 'znver3' or 'skylake-avx512'."""
    import llvmlite.binding as llvm

    return llvm.get_host_cpu_name()


def host_cpu() -> str:
    """One line naming the host CPU: '<numba target> (<model name>)', e.g. 'znver3 (AMD EPYC)'."""
    return f"{numba_target_cpu()} ({cpu_model_name()})"


@contextlib.contextmanager
def single_threaded_children() -> Iterator[None]:
    """One BLAS / OpenMP / numba thread in the processes started inside the block (they inherit the environment), so
    n worker processes do not oversubscribe the cores; the environment is restored on exit."""
    names = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")
    old = {n: os.environ.get(n) for n in names}
    os.environ.update({n: "1" for n in names})
    try:
        yield
    finally:
        for n, v in old.items():
            if v is None:
                os.environ.pop(n, None)
            else:
                os.environ[n] = v
