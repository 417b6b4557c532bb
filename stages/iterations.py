"""The config a stage sees in each of the paper's data-collection iterations."""

from __future__ import annotations

from typing import Any

from expoctl.errors import InputError
from stages.keys import LAST_ITERATION
from stages.project import RESOLVED_CONFIG


def for_iteration(cfg: dict[str, Any], iteration: int) -> dict[str, Any]:
    """The config a stage sees in the paper's data-collection iteration `iteration` (1 … LAST_ITERATION).

    Iteration N ≥ 2 (the previous iteration's network becomes camera 1's reference, more data is collected, and the
    model is retrained on all data so far) runs the same stage code on its own paths: `paths` becomes
    `iteration<N>.paths` over the base paths, `paths_prev` holds the previous iteration's paths (collect's reference
    model, the tables features reuses, the model train keeps when the iteration is disabled), `raw_dirs_prev` every
    earlier iteration's raw directory (ingest reads them all, oldest first) and `iteration_block` the `iteration<N>`
    block itself.
    """
    if iteration == 1:
        return cfg
    if not 2 <= iteration <= LAST_ITERATION:
        raise InputError(f"--iteration must be 1 … {LAST_ITERATION}, got {iteration}")
    paths = [cfg.get("paths") or {}]
    for k in range(2, iteration + 1):
        block = cfg.get(f"iteration{k}")
        if not isinstance(block, dict) or not isinstance(block.get("paths"), dict):
            raise InputError(f"{RESOLVED_CONFIG}: config key 'iteration{k}.paths' is missing")
        paths.append({**paths[0], **block["paths"]})
    out = dict(cfg)
    out["paths"] = paths[-1]
    out["paths_prev"] = paths[-2]
    out["raw_dirs_prev"] = [p["raw_dir"] for p in paths[:-1]]
    out["iteration_block"] = cfg[f"iteration{iteration}"]
    out["iteration"] = iteration
    return out
