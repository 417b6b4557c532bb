"""ingest stage: data/raw/ → data/frames.parquet + data/images/ (see expoctl.raw.ingest)."""

from __future__ import annotations

import logging
import time

from expoctl.raw.ingest import IngestConfig, ingest
from stages.common import PROJECT_ROOT, stage_main

log = logging.getLogger(__name__)


def run(cfg: dict, tracker) -> None:
    paths = cfg["paths"]
    icfg = IngestConfig.from_dict(cfg["ingest"])
    t0 = time.perf_counter()
    raw_dirs = [PROJECT_ROOT / paths["raw_dir"]]
    if cfg.get("iteration", 1) > 1:  # a later iteration trains on all data so far: earlier sequences come first
        raw_dirs = [PROJECT_ROOT / d for d in cfg["raw_dirs_prev"]] + raw_dirs
    frames = ingest(raw_dirs, PROJECT_ROOT / paths["frames"], PROJECT_ROOT / paths["images_dir"],
                    icfg, project_root=PROJECT_ROOT, progress=log.info)
    seconds = time.perf_counter() - t0
    per_split = frames.groupby("split")["sequence"].nunique().to_dict()
    metrics = {"n_sequences": frames["sequence"].nunique(), "n_images": len(frames), "seconds": seconds,
               "images_per_s": len(frames) / max(seconds, 1e-9)}
    metrics.update({f"n_sequences_{k}": v for k, v in per_split.items()})
    metrics.update({f"n_frames_section_{k}": v for k, v in frames.groupby("section").size().items()})
    tracker.log_metrics(metrics)
    log.info("%d sequences, %d images in %.1f s (%s)", metrics["n_sequences"], len(frames), seconds, per_split)


if __name__ == "__main__":
    stage_main("ingest", run)
