"""The reproducible numeric mode: every CPU-dependent choice of the numeric libraries pinned to one baseline.

The libraries expoctl computes with pick code paths by CPU at run time: torch's oneDNN (convolutions) and ATen
kernels, MKL (torch's BLAS), OpenBLAS (numpy's BLAS), numpy's and OpenCV's SIMD dispatch, numba's code generation
for the host, and the thread counts that split reductions. Each reads a documented switch, most of them once, when
the library is loaded. `numerics.mode: pinned` (config group `numerics`, docs/reproducibility.md) sets all of them to
the x86-64-v3 (AVX2 + FMA, "haswell") baseline, so an AVX-512 host runs the kernels an AVX2 host runs;
`numerics.mode: host` leaves every library its own choice (the fastest on this CPU, the bytes of this CPU).

Measured on the hosts we have (benchmarks/cpu_dispatch.py, docs/reproducibility.md): on an AVX-512 host, oneDNN's
ISA (`ONEDNN_MAX_CPU_ISA`), ATen's capability and torch's thread count change trained weights; on an AVX2 AMD host,
MKL's CNR branch (`MKL_CBWR`) does; numba and OpenCV switches changed nothing. They are pinned anyway: a host with
other kernels (an Intel CPU with AVX-512 FP16, a numpy with AVX-512 sort or SVML paths) could differ where ours do not.

Why the environment: the switches are read at import (oneDNN, ATen, MKL, OpenBLAS, numpy, OpenCV) or at numba's
first compile, so they must be set before any of those libraries is imported: the stage entry points set them first
(stages/__init__.py), worker processes inherit them (spawn and the fork server copy the environment), and Ray tasks
get them through their `runtime_env` (`expoctl.parallel.runtime_env`, which forwards `forwarded_env()`). This module
imports nothing heavy; it only describes and applies the environment.
"""

from __future__ import annotations

import os
import platform
import sys
from collections.abc import MutableMapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from expoctl.config_reader import Problems, param, read_config

MODES = ("pinned", "host")
BASELINE = "x86-64-v3"
#: /proc/cpuinfo flags an x86-64-v3 CPU has (AVX2, FMA, BMI1/2, F16C, MOVBE, LZCNT = 'abm'): without them the
#: pinned libraries fall back to older kernels than the baseline's, so such a host cannot reproduce the bytes
BASELINE_FLAGS = ("avx", "avx2", "fma", "bmi1", "bmi2", "f16c", "movbe", "abm")
#: flags recorded with a run: what decides which kernels a library may pick on this host
RECORDED_FLAGS = ("avx2", "fma", "avx512f", "avx512bw", "avx512vl", "avx512_vnni", "avx512_bf16", "avx512_fp16",
                  "avx_vnni", "amx_tile")
#: numpy 2.4's dispatch targets above the baseline (numpy._core._multiarray_umath.__cpu_dispatch__: X86_V3 X86_V4
#: AVX512_ICL AVX512_SPR); disabled, numpy runs its X86_V3 kernels. Names outside that list are refused with an
#: ImportWarning that Python hides by default and nothing is disabled: the AVX512F … list benchmarks/cpu_dispatch.py
#: used was such a no-op (its "numpy: no change" row measured nothing). Targets this CPU lacks are accepted silently
NPY_ABOVE_BASELINE = "X86_V4 AVX512_ICL AVX512_SPR"
#: OpenCV 5.0's dispatched targets are SSE4_1 … AVX2 and AVX512_SKX (cv2.getBuildInformation()); disabling the
#: feature AVX512F turns AVX512_SKX off. OpenCV prints a line on every import where the CPU lacks the feature
#: ("Trying to disable unavailable CPU feature"), so a stage process sets it only on an AVX-512 host
#: (`environment`); a Ray task always gets it (its node's CPU is unknown here; worker logs are not shown)
OPENCV_ABOVE_BASELINE = "AVX512F"

#: variable -> value in the pinned mode, each with why
PINNED_ENV: dict[str, str] = {
    # torch's oneDNN convolutions: measured, its AVX-512 kernels give other trained weights than its AVX2 ones
    "ONEDNN_MAX_CPU_ISA": "AVX2",
    "DNNL_MAX_CPU_ISA": "AVX2",  # the name oneDNN releases before 2.x read; harmless where unknown
    # ATen's vectorised kernels: measured, `default` (no SIMD) against `avx2` changes weights; avx2 is what torch
    # chooses on an AVX2 host, and caps an AVX-512 one there
    "ATEN_CPU_CAPABILITY": "avx2",
    # torch's BLAS is MKL (torch.__config__.show(): BLAS_INFO=mkl): conditional numerical reproducibility on the
    # AVX2 code path, and no AVX-512 dispatch. Measured: on an AMD CPU MKL's default path is another one, and the
    # fixture's trained weights differ without MKL_CBWR (docs/reproducibility.md)
    "MKL_CBWR": "AVX2",
    "MKL_ENABLE_INSTRUCTIONS": "AVX2",
    # numpy's BLAS is OpenBLAS built with DYNAMIC_ARCH: its kernel set chosen per CPU, pinned to Haswell's
    "OPENBLAS_CORETYPE": "Haswell",
    # numba's code generation: the baseline CPU with its own feature set. NUMBA_CPU_NAME alone would keep the host's
    # features (numba.core.codegen: features come from the host unless NUMBA_CPU_FEATURES is set), so "" says
    # "haswell's features"
    "NUMBA_CPU_NAME": "haswell",
    "NUMBA_CPU_FEATURES": "",
    "NPY_DISABLE_CPU_FEATURES": NPY_ABOVE_BASELINE,
    "OPENCV_CPU_DISABLE": OPENCV_ABOVE_BASELINE,
    # thread counts: every multi-threaded call either takes its count from the config (train.num_threads,
    # controllers.learned.num_threads, features' cv2.setNumThreads(1)) or runs on one thread, never on "all cores"
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    # torch.use_deterministic_algorithms on CUDA (train.device: cuda) refuses cuBLAS without a fixed workspace
    "CUBLAS_WORKSPACE_CONFIG": ":4096:8",
}

#: the modules whose import reads the switches: set after one of them is loaded, a switch does not take effect
READ_AT_IMPORT = ("torch", "numpy", "cv2", "numba")


@dataclass(frozen=True)
class NumericsConfig:
    """Config group `numerics` (conf/numerics/default.yaml)."""

    #: pinned: every CPU-dependent choice at the x86-64-v3 baseline (same bytes on every such host); host: each
    #: library's own choice for this CPU
    mode: str = param("pinned", choices=MODES)

    @classmethod
    def from_dict(cls, d: Any, key: str = "numerics", problems: Problems | None = None) -> "NumericsConfig":
        return read_config(cls, d, key, problems)

    @classmethod
    def from_resolved(cls, cfg: Any, problems: Problems | None = None) -> "NumericsConfig":
        """From the resolved config's `numerics` block (absent: the default)."""
        top = cfg if isinstance(cfg, dict) else {}
        return cls.from_dict(top.get("numerics"), "numerics", problems)

    @property
    def pinned(self) -> bool:
        return self.mode == "pinned"


def environment(config: NumericsConfig, flags: set[str] | None = None) -> dict[str, str]:
    """The environment variables the mode sets in a process on this host ({} for host: nothing is touched).
    OPENCV_CPU_DISABLE only where the CPU has AVX-512 (elsewhere there is nothing to disable, and OpenCV would say so
    on stderr in every process)."""
    if not config.pinned:
        return {}
    env = dict(PINNED_ENV)
    if "avx512f" not in (cpu_flags() if flags is None else flags):
        env.pop("OPENCV_CPU_DISABLE")
    return env


def apply_environment(config: NumericsConfig, environ: MutableMapping[str, str] | None = None) -> list[str]:
    """Set the mode's variables in `environ` (default os.environ), overriding what the user's shell set: a pinned run
    must not depend on it. Returns the libraries among READ_AT_IMPORT that this process has already imported, for
    which the variables come too late (empty in a stage process, which calls this first)."""
    env = os.environ if environ is None else environ
    env.update(environment(config))
    return [m for m in READ_AT_IMPORT if m in sys.modules] if config.pinned else []


def forwarded_env(environ: MutableMapping[str, str] | None = None) -> dict[str, str]:
    """The pinned variables this process runs with, for a worker that does not inherit its environment (a Ray task
    on another node): {} when the process is not pinned."""
    env = os.environ if environ is None else environ
    if any(env.get(k) != v for k, v in PINNED_ENV.items() if k != "OPENCV_CPU_DISABLE"):
        return {}
    return dict(PINNED_ENV)  # with OPENCV_CPU_DISABLE: the worker's node may have AVX-512 where this one has not


def apply_in_process(config: NumericsConfig) -> bool:
    """What the mode sets through a library call rather than the environment: torch's deterministic algorithms
    (warn_only, so an op without a deterministic kernel warns instead of stopping a stage; on the CPU the ops expoctl
    uses have one). Only when torch is already loaded (the train stage imports it first); True if applied."""
    if not config.pinned or "torch" not in sys.modules:
        return False
    import torch

    torch.use_deterministic_algorithms(True, warn_only=True)
    return True


# ------------------------------------------------------------------------------------------------ the record


def cpu_flags(cpuinfo: Path = Path("/proc/cpuinfo")) -> set[str]:
    """The CPU's feature flags (Linux /proc/cpuinfo; empty elsewhere)."""
    try:
        for line in cpuinfo.read_text(errors="replace").splitlines():
            key, sep, value = line.partition(":")
            if sep and key.strip() == "flags":
                return set(value.split())
    except OSError:
        pass
    return set()


def meets_baseline(flags: set[str] | None = None) -> bool:
    """Whether this CPU has every x86-64-v3 feature (on another architecture: False)."""
    flags = cpu_flags() if flags is None else flags
    return platform.machine().lower() in ("x86_64", "amd64") and all(f in flags for f in BASELINE_FLAGS)


def baseline_warning(config: NumericsConfig, flags: set[str] | None = None) -> str | None:
    """A line to print when the pinned mode cannot give the baseline's bytes on this host, else None."""
    if not config.pinned or meets_baseline(flags):
        return None
    flags = cpu_flags() if flags is None else flags
    missing = [f for f in BASELINE_FLAGS if f not in flags]
    what = (f"lacks {', '.join(missing)}" if platform.machine().lower() in ("x86_64", "amd64")
            else f"is {platform.machine()}, not x86-64")
    return (f"numerics.mode is pinned to {BASELINE}, but this CPU {what}: its libraries run older kernels, so its "
            f"outputs may differ from other hosts' (docs/reproducibility.md)")


#: distributions whose versions decide bytes as much as the CPU does
VERSIONED = ("numpy", "numba", "llvmlite", "torch", "opencv-python-headless", "opencv-python", "onnxruntime", "pandas",
             "pyarrow", "scipy")


def library_versions() -> dict[str, str]:
    """Installed versions, read from package metadata (no import)."""
    from importlib import metadata

    # glibc's libm (exp, log, pow: what numba's kernels call) picks FMA variants per CPU and changes between
    # releases: the one library the pins cannot reach, so its version is recorded with the rest
    libc, libc_version = platform.libc_ver()
    out = {"python": platform.python_version(), **({libc: libc_version} if libc else {})}
    for dist in VERSIONED:
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            continue
    return out


def record(config: NumericsConfig, late: list[str] | None = None) -> dict[str, Any]:
    """Which mode this process runs in, on which CPU, with which libraries: what a run records (MLflow tags and
    reports/numerics.json). `late`: the libraries `apply_environment` found already imported."""
    from expoctl.host import cpu_model_name

    flags = cpu_flags()
    out: dict[str, Any] = {
        "mode": config.mode,
        "baseline": BASELINE if config.pinned else None,
        "environment": {k: os.environ.get(k) for k in PINNED_ENV},
        "applied_before_import": not late,
        "cpu": {"model": cpu_model_name(), "machine": platform.machine(),
                "flags": {f: (f in flags) for f in RECORDED_FLAGS},
                "meets_baseline": meets_baseline(flags)},
        "versions": library_versions(),
    }
    if late:
        out["imported_too_early"] = list(late)
    try:
        from expoctl.host import numba_target_cpu

        out["cpu"]["llvm_host_cpu"] = numba_target_cpu()
    except ImportError:  # llvmlite missing: nothing numba would compile anyway
        pass
    if "torch" in sys.modules:  # what ATen chose; importing torch only to ask would cost a second
        torch = sys.modules["torch"]
        out["torch"] = {"cpu_capability": torch.backends.cpu.get_cpu_capability(),
                        "deterministic_algorithms": torch.are_deterministic_algorithms_enabled(),
                        "num_threads": torch.get_num_threads()}
    return out


def tags(rec: dict[str, Any]) -> dict[str, str]:
    """The record as flat MLflow tags (`numerics.*`)."""
    cpu = rec["cpu"]
    out = {"numerics.mode": rec["mode"], "numerics.applied_before_import": str(rec["applied_before_import"]),
           "numerics.cpu_meets_baseline": str(cpu["meets_baseline"]),
           "numerics.cpu_flags": ",".join(f for f, on in cpu["flags"].items() if on),
           "numerics.versions": ", ".join(f"{k} {v}" for k, v in rec["versions"].items())}
    if "torch" in rec:
        out["numerics.torch_cpu_capability"] = str(rec["torch"]["cpu_capability"])
    return out
