"""Shared test fixtures."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from expoctl.numerics import PINNED_ENV

# numba compiles for the pinned mode's CPU target here too (haswell's features, expoctl.numerics.PINNED_ENV), the
# target every pipeline stage that the tests start as a subprocess compiles for (stages/numerics.py). numba caches
# one build per target, and the renderer's cold build takes ~13 min of one core (seen 2026-12-07: the test process
# built it for this host's CPU, then the pipeline test's collect stage built it again for haswell). Set before numba
# is imported (it reads the variables at import); outputs on an x86-64-v3 host do not depend on it
# (benchmarks/cpu_dispatch.py). A shell that chose a numba target keeps it.
if "numba" not in sys.modules and "NUMBA_CPU_NAME" not in os.environ:
    os.environ["NUMBA_CPU_NAME"] = PINNED_ENV["NUMBA_CPU_NAME"]
    os.environ["NUMBA_CPU_FEATURES"] = PINNED_ENV["NUMBA_CPU_FEATURES"]

import pytest  # noqa: E402
from synthetic_raw import write_synthetic_sequence  # noqa: E402


@pytest.fixture
def raw_dir(tmp_path: Path) -> Path:
    """data/raw with one train, one validation and one test sequence."""
    root = tmp_path / "raw"
    for i, split in enumerate(("train", "validation", "test")):
        write_synthetic_sequence(root / split / f"seq_{split}", seed=i)
    return root
