"""collect stage: drive the simulated dual-camera rig → data/raw/<split>/<sequence>/ (see expoctl.sim.collect)."""

from __future__ import annotations

import logging
import sys
import time

from expoctl.sim.collect import CollectInputs, collect
from stages.common import PROJECT_ROOT, stage_main

log = logging.getLogger(__name__)


def later_iteration_config(cfg: dict) -> dict:
    """collect_iter<N>: `iteration<N>.collect` merged over `collect`; the previous iteration's network drives camera 1.

    Disabled (`iteration<N>.enabled: false`): every split records zero sequences, so the iteration adds no data.
    """
    from expoctl.errors import ConfigError
    from expoctl.world.cities import deep_merge

    n, block = cfg["iteration"], cfg["iteration_block"]
    enabled = block.get("enabled")
    if not isinstance(enabled, bool):
        raise ConfigError(f"iteration{n}.enabled", f"must be true or false, got {enabled!r}")
    collect_cfg = deep_merge(cfg["collect"], block.get("collect") or {})
    if not enabled:
        collect_cfg["splits"] = {k: {**v, "n_sequences": 0} for k, v in collect_cfg["splits"].items()}
    controllers = dict(cfg.get("controllers") or {})
    if collect_cfg.get("reference_controller") == "learned":
        checkpoint = PROJECT_ROOT / cfg["paths_prev"]["model"]
        if enabled and not checkpoint.is_file():
            key = "paths.model" if n == 2 else f"iteration{n - 1}.paths.model"
            raise ConfigError(key, f"{checkpoint}: the iteration-{n - 1} model is missing (run its train stage)")
        controllers["learned"] = {**(controllers.get("learned") or {}), "checkpoint": str(checkpoint)}
    return {**cfg, "collect": collect_cfg, "controllers": controllers}


def run(cfg: dict, tracker) -> None:
    if cfg.get("iteration", 1) > 1:
        cfg = later_iteration_config(cfg)
    inputs = CollectInputs.from_resolved(cfg)  # every config problem at once, before any work
    out_dir = PROJECT_ROOT / cfg["paths"]["raw_dir"]
    t0 = time.perf_counter()
    # a bar on a terminal; under DVC (no tty) one log line per finished sequence
    summaries = collect(inputs, out_dir, progress=True if sys.stderr.isatty() else log.info, project_root=PROJECT_ROOT)
    seconds = time.perf_counter() - t0
    n_frames = sum(s["n_frames"] for s in summaries)
    metrics = {
        "n_sequences": len(summaries),
        "n_frame_pairs": n_frames,
        "n_dynamic_sections": sum(s["n_dynamic_sections"] for s in summaries),
        "seconds": seconds,
        "frame_pairs_per_s": n_frames / max(seconds, 1e-9),
    }
    for split in ("train", "validation", "test"):
        metrics[f"n_sequences_{split}"] = sum(1 for s in summaries if s["split"] == split)
        metrics[f"n_frame_pairs_{split}"] = sum(s["n_frames"] for s in summaries if s["split"] == split)
    tracker.log_metrics(metrics)
    for s in summaries:
        log.info("%s: %d frames, %d dynamic sections, camera-1 exposure %.0f–%.0f µs, gain up to %.1f dB",
                 s["sequence"], s["n_frames"], s["n_dynamic_sections"], s["cam1_exposure_us_min"],
                 s["cam1_exposure_us_max"], s["cam1_gain_db_max"])
    log.info("%d sequences, %d frame pairs in %.1f s → %s", len(summaries), n_frames, seconds, out_dir)


if __name__ == "__main__":
    stage_main("collect", run)
