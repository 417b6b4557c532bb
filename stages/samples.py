"""samples stage: frames + labels → data/samples.parquet (see expoctl.labels.samples)."""

from __future__ import annotations

import dataclasses
import logging

from expoctl.errors import InputError
from expoctl.io import write_parquet
from expoctl.labels.samples import SampleConfig, build_samples, summarise_samples
from stages.common import PROJECT_ROOT, stage_main
from stages.labels import read_table

log = logging.getLogger(__name__)


def run(cfg: dict, tracker) -> None:
    paths = cfg["paths"]
    scfg = SampleConfig.from_dict(cfg.get("samples"))
    frames = read_table(PROJECT_ROOT / paths["frames"], paths["frames"], "ingest")
    labels = read_table(PROJECT_ROOT / paths["labels"], paths["labels"], "labels")
    samples = build_samples(frames, labels, scfg, names={"frames": str(paths["frames"]), "labels": str(paths["labels"])})
    if samples.empty:
        raise InputError(f"{paths['labels']}: no labelled time step t has frames t−1 and t−2 in its sequence, "
                         f"so there are no samples")
    write_parquet(samples, PROJECT_ROOT / paths["samples"])
    summary = summarise_samples(samples)
    tracker.log_params({"effective.samples": dataclasses.asdict(scfg)})
    tracker.log_metrics({"n_samples": len(samples), **summary})
    log.info("%d samples (%s)", len(samples), {k: v["n_samples"] for k, v in summary.items()})


if __name__ == "__main__":
    stage_main("samples", run)
