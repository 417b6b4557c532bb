"""The DVC contract: which keys of configs/resolved.yaml each stage reads, and the stages' names.

dvc.yaml declares exactly these keys as each stage's `params` (tests/pipeline/test_dvc_yaml.py checks that the two
agree), so `dvc repro` re-runs a stage only when a key it reads changes. The same keys are what a stage's MLflow run
logs as params and hashes into its `config_hash` tag.
"""

from __future__ import annotations

import hashlib
import json
import re
from typing import Any

from expoctl.errors import InputError
from stages.project import RESOLVED_CONFIG

#: Data-collection iterations 2 … LAST_ITERATION run as the DVC `foreach` stages `<name>_iter@<N>` (conf/config.yaml
#: `iteration<N>` blocks; dvc.yaml `vars: later_iterations`). The final model, which evaluate drives, is the one
#: select_model chooses among them (paths.final_model).
LAST_ITERATION = 3

#: The keys each iteration-1 stage reads (the later iterations' additions are in `stage_keys`).
STAGE_KEYS: dict[str, list[str]] = {
    # `parallel` (where the jobs run, never what they compute) is read by the stages that fan out
    "collect": ["seed", "sensor", "world", "rig", "collect", "controllers.agae", "paths.raw_dir", "parallel"],
    "ingest": ["ingest", "paths.raw_dir", "paths.frames", "paths.images_dir"],
    "features": ["features", "paths.frames", "paths.features", "paths.matches", "parallel"],
    "labels": ["labels", "paths.frames", "paths.features", "paths.matches", "paths.labels", "paths.reports_dir"],
    "samples": ["samples", "paths.frames", "paths.labels", "paths.samples"],
    "train": ["seed", "model", "train", "sensor", "paths.samples", "paths.frames", "paths.images_dir", "paths.model",
              "paths.reports_dir"],
    # select_model reads every iteration's enabled flag and model path: the candidates
    "select_model": ["seed", "sensor", "world", "rig", "controllers", "features", "evaluate", "select_model",
                     "paths.model", "paths.final_model", "paths.frames", "paths.reports_dir", "parallel"]
                    + [f"iteration{n}.{k}" for n in range(2, LAST_ITERATION + 1) for k in ("enabled", "paths.model")],
    "evaluate": ["seed", "sensor", "world", "rig", "controllers", "features", "evaluate", "paths.final_model",
                 "paths.frames", "paths.reports_dir", "parallel"],
    "report": ["report", "paths.reports_dir", "paths.final_model"],
}

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
    """Config keys of a DVC stage. `<name>_iter@<N>` reads its base stage's keys, its own `iteration<N>` block's
    `enabled` and `paths`, and every earlier iteration's paths (its raw directories are ingested again, the previous
    model is collect's reference, the previous tables are reused); collect also reads `iteration<N>.collect`."""
    base, n = split_stage_name(stage)
    if n == 1:
        return STAGE_KEYS.get(stage, [])
    keys = STAGE_KEYS[base] + [f"iteration{n}.enabled", f"iteration{n}.paths"]
    keys += [f"iteration{k}.paths" for k in range(2, n)]
    if base == "collect":  # iterations ≥ 2 drive camera 1 with the learned network (its latency_frames) if it
        # passes the saturation probe (`iteration<N>.reference_gate`)
        keys += ["controllers.learned", f"iteration{n}.collect", f"iteration{n}.reference_gate",
                 "select_model.probe"] + (["paths.model"] if n == 2 else [])
    return keys


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
