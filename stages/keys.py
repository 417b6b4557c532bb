"""The config keys of configs/resolved.yaml each stage reads, and the stages' names.

The keys come from the stage table (stages/table.py), which dvc.yaml is generated from, so a stage's DVC `params`
are exactly these keys and `dvc repro` re-runs a stage only when a key it reads changes. The same keys are what a
stage's MLflow run logs as params and hashes into its `config_hash` tag.
"""

from __future__ import annotations

import hashlib
import json
import re
from typing import Any

from expoctl.errors import InputError
from stages.project import RESOLVED_CONFIG
from stages.table import LAST_ITERATION, STAGE_BY_NAME, STAGES, config_keys

__all__ = ["LAST_ITERATION", "STAGE_KEYS", "config_hash", "runtime_keys", "select_keys", "split_stage_name",
           "stage_keys", "stage_name"]

#: The keys each iteration-1 stage reads (stages that read none, guard and compose, are not listed); the later
#: iterations' are `stage_keys("<name>_iter@<N>")`.
STAGE_KEYS: dict[str, list[str]] = {s.name: config_keys(s, 1) for s in STAGES if config_keys(s, 1)}

# DVC names a foreach stage `<stage>@<key>`; ours are `collect_iter@2`, `train_iter@3`, …
_ITERATION_STAGE = re.compile(r"^(?P<base>\w+)_iter@(?P<n>\d+)$")


def stage_name(base: str, iteration: int) -> str:
    """The DVC (and MLflow run) name of stage `base` in data-collection iteration `iteration`."""
    return base if iteration == 1 else f"{base}_iter@{iteration}"


def split_stage_name(stage: str) -> tuple[str, int]:
    """'features_iter@3' → ('features', 3); 'features' → ('features', 1)."""
    m = _ITERATION_STAGE.match(stage)
    if m and int(m["n"]) >= 2:
        return m["base"], int(m["n"])
    return stage, 1


def stage_keys(stage: str) -> list[str]:
    """Config keys of a DVC stage (stages/table.py `config_keys`): `<name>_iter@<N>` reads its base stage's keys in
    iteration N, its own `iteration<N>` block's `enabled` and `paths`, every earlier iteration's paths, and what the
    table adds for later iterations (collect: `iteration<N>.collect`, its reference gate and the probe). [] for a
    name that is no stage of the table, or no iteration of one."""
    base, n = split_stage_name(stage)
    entry = STAGE_BY_NAME.get(base)
    if entry is None or (n > 1 and (not entry.iterated or n > LAST_ITERATION)):
        return []
    return config_keys(entry, n)


def runtime_keys(stage: str) -> list[str]:
    """The keys a DVC stage reads that only choose where and how fast it runs (stages/table.py `Stage.runtime_keys`):
    not its DVC params, not in its `config_hash`; its MLflow run logs them. [] for a name that is no stage."""
    base, _ = split_stage_name(stage)
    entry = STAGE_BY_NAME.get(base)
    return list(entry.runtime_keys) if entry is not None and stage_keys(stage) else []


def select_keys(cfg: dict[str, Any], keys: list[str]) -> dict[str, Any]:
    """The sub-config named by dotted keys, e.g. ["features", "paths.frames"] → {"features": …, "paths.frames": …}."""
    out = {}
    for key in keys:
        node: Any = cfg
        for part in key.split("."):
            if not isinstance(node, dict) or part not in node:
                raise InputError(f"{RESOLVED_CONFIG}: config key '{key}' is missing")
            node = node[part]
        out[key] = node
    return out


def config_hash(sub: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(sub, sort_keys=True, default=str).encode()).hexdigest()[:16]
