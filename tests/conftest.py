"""Shared test fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest
from synthetic_raw import write_synthetic_sequence


@pytest.fixture
def raw_dir(tmp_path: Path) -> Path:
    """data/raw with one train, one validation and one test sequence."""
    root = tmp_path / "raw"
    for i, split in enumerate(("train", "validation", "test")):
        write_synthetic_sequence(root / split / f"seq_{split}", seed=i)
    return root
