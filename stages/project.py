"""Where the project and its resolved config live, and reading that config."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from expoctl.errors import InputError

PROJECT_ROOT = Path(__file__).resolve().parents[1]
RESOLVED_CONFIG = PROJECT_ROOT / "configs" / "resolved.yaml"
#: Real rig recordings' home: no stage's output, so `dvc repro` never deletes it (`collect.source: recordings`
#: copies it into the collect stage's output, data/raw). Relative to the project root.
RECORDINGS_DIR = "data/recordings"


def main_project_root(start: Path = PROJECT_ROOT) -> Path:
    """The user's project root, also from inside a `dvc exp run --queue` workspace copy.

    DVC runs queued experiments in copies under `<root>/.dvc/tmp/exps/...`; a store path computed there would be lost
    with the copy, so cut the path at `.dvc`.
    """
    parts = start.parts
    if ".dvc" in parts:
        return Path(*parts[: parts.index(".dvc")])
    return start


def load_resolved(path: Path = RESOLVED_CONFIG) -> dict[str, Any]:
    """configs/resolved.yaml, which the compose stage writes from conf/ and params.yaml's overrides."""
    if not path.exists():
        raise InputError(f"{path}: missing; run the compose stage first (dvc repro compose)")
    cfg = yaml.safe_load(path.read_text())
    if not isinstance(cfg, dict):
        raise InputError(f"{path}: not a YAML mapping")
    return cfg
