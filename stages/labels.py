"""labels stage: features + matches → data/labels.parquet, reports/labels.md + labels.json (see expoctl.labels)."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

import pandas as pd

from expoctl.errors import InputError
from expoctl.io import write_json, write_parquet, write_text
from expoctl.labels.report import compute_label_stats, flat_metrics, render_markdown
from expoctl.labels.targets import LabelConfig, compute_labels
from stages.common import PROJECT_ROOT, stage_main

log = logging.getLogger(__name__)


def read_table(path: Path, shown: str, producer: str) -> pd.DataFrame:
    """Read a Parquet input; a missing or unreadable file is an InputError naming it and the stage that makes it."""
    if not path.exists():
        raise InputError(f"{shown}: missing; run the {producer} stage first")
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several types for a corrupt file
        raise InputError(f"{shown}: not a readable Parquet file ({exc})") from exc


def run(cfg: dict, tracker) -> None:
    paths = cfg["paths"]
    lcfg = LabelConfig.from_dict(cfg.get("labels"))
    frames = read_table(PROJECT_ROOT / paths["frames"], paths["frames"], "ingest")
    features = read_table(PROJECT_ROOT / paths["features"], paths["features"], "features")
    matches = read_table(PROJECT_ROOT / paths["matches"], paths["matches"], "features")
    names = {k: str(paths[k]) for k in ("frames", "features", "matches")}
    labels = compute_labels(frames, features, matches, lcfg, names=names)
    if labels.empty:  # nothing to train on: stop here rather than in the train stage
        first, last = lcfg.latency_frames, lcfg.latency_frames + lcfg.window - 1
        raise InputError(f"{paths['frames']}: no time step has a complete window t+{first} … t+{last} "
                         f"({len(frames) // 2} frames; each sequence needs at least {last + 1} consecutive)")
    stats = compute_label_stats(labels, frames, dataclasses.asdict(lcfg))
    reports_dir = PROJECT_ROOT / paths["reports_dir"]
    write_parquet(labels, PROJECT_ROOT / paths["labels"])
    write_json(stats, reports_dir / "labels.json")
    write_text(render_markdown(stats), reports_dir / "labels.md")
    tracker.log_params({"effective.labels": dataclasses.asdict(lcfg)})
    tracker.log_metrics(flat_metrics(stats))
    tracker.log_artifact(reports_dir / "labels.md")
    tracker.log_artifact(reports_dir / "labels.json")
    log.info("%d labelled time steps of %d frames", stats["n_labelled_time_steps"], stats["n_frames"])
    for line in stats["findings"]:
        log.info("%s", line)


if __name__ == "__main__":
    stage_main("labels", run)
