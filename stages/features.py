"""features stage: data/frames.parquet → data/features.parquet + data/matches.parquet (expoctl.features.pipeline)."""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path

import pandas as pd

from expoctl.errors import InputError
from expoctl.features.pipeline import FeaturesConfig, compute_features
from expoctl.io import write_parquet
from expoctl.parallel import ParallelConfig
from stages.common import PROJECT_ROOT, stage_main

log = logging.getLogger(__name__)


def run(cfg: dict, tracker, project_root: Path | None = None) -> None:
    root = Path(project_root or PROJECT_ROOT)
    paths = cfg["paths"]
    fcfg = FeaturesConfig.from_dict(cfg["features"])  # ConfigError before any work
    parallel = ParallelConfig.from_resolved(cfg)  # where the sequences run
    frames_path = root / paths["frames"]
    if not frames_path.is_file():
        raise InputError(f"{frames_path}: frames table missing; run the ingest stage first")
    try:
        frames = pd.read_parquet(frames_path)
    except Exception as exc:  # pyarrow raises several types for a damaged file
        raise InputError(f"{frames_path}: not a readable Parquet file ({exc})") from None

    effective = {"frontends": list(fcfg.frontends)}
    for name in fcfg.frontends:  # each front end's typed config, defaults filled in
        effective[name] = dataclasses.asdict(fcfg.config(name))
    tracker.log_params({"effective": effective})

    t0 = time.perf_counter()
    reused_features, reused_matches, todo = _reusable_previous_iteration(cfg, root, frames, fcfg)
    features, matches = (compute_features(todo, root, fcfg, progress=True, parallel=parallel) if len(todo)
                         else (None, None))
    if reused_features is not None:
        features = pd.concat([t for t in (reused_features, features) if t is not None], ignore_index=True)
        matches = pd.concat([t for t in (reused_matches, matches) if t is not None], ignore_index=True)
    seconds = time.perf_counter() - t0
    write_parquet(features, root / paths["features"])
    write_parquet(matches, root / paths["matches"])

    n_images = int(len(frames))
    metrics = {"n_images": n_images, "n_pairs": int(len(matches) // max(len(fcfg.frontends), 1)),
               "n_sequences": int(frames["sequence"].nunique()), "seconds": seconds,
               "images_per_s": n_images / max(seconds, 1e-9)}
    for name in fcfg.frontends:
        f = features[features.frontend == name]
        m = matches[matches.frontend == name]
        same_camera = m[m.cam_from == m.cam_to]
        metrics.update({
            f"{name}.median_n_features": float(f.n_features.median()),
            f"{name}.median_n_matches": float(m.n_matches.median()) if len(m) else 0.0,
            f"{name}.median_n_inliers": float(m.n_inliers.median()) if len(m) else 0.0,
            f"{name}.median_n_inliers_same_camera": float(same_camera.n_inliers.median()) if len(m) else 0.0,
            f"{name}.min_n_inliers": float(m.n_inliers.min()) if len(m) else 0.0,
        })
    tracker.log_metrics(metrics)
    log.info("%d images, %d pairs in %.1f s (%.1f images/s); %s", n_images, metrics["n_pairs"], seconds,
             metrics["images_per_s"],
             ", ".join(f"{n}: median {metrics[f'{n}.median_n_features']:.0f} features, "
                       f"{metrics[f'{n}.median_n_inliers']:.0f} inliers" for n in fcfg.frontends))


def _reusable_previous_iteration(cfg: dict, root: Path, frames: pd.DataFrame, fcfg):
    """A later iteration re-ingests the earlier iterations' sequences unchanged: take their counts from the previous
    iteration's tables instead of recomputing them. A sequence is reused only if its frames rows are identical in both
    iterations and the previous tables hold every front end configured now. Returns (features, matches, frames still
    to compute)."""
    if cfg.get("iteration", 1) == 1:
        return None, None, frames
    p1 = cfg["paths_prev"]
    paths = [root / p1[k] for k in ("frames", "features", "matches")]
    if not all(p.is_file() for p in paths):
        return None, None, frames
    frames1, features1, matches1 = (pd.read_parquet(p) for p in paths)
    key = ["sequence", "frame_id", "camera", "gain_db", "exposure_us", "image_path"]
    reuse = []
    for seq, rows in frames.groupby("sequence"):
        old = frames1[frames1.sequence == seq]
        if len(old) == len(rows) and set(fcfg.frontends) <= set(features1.loc[features1.sequence == seq, "frontend"]) \
                and old[key].sort_values(key[:3]).reset_index(drop=True).equals(
                    rows[key].sort_values(key[:3]).reset_index(drop=True)):
            reuse.append(seq)
    log.info("iteration %d: reusing the previous iteration's counts of %d of %d sequences", cfg["iteration"], len(reuse),
             frames["sequence"].nunique())
    keep = lambda t: t[t.sequence.isin(reuse) & t.frontend.isin(fcfg.frontends)]  # noqa: E731
    return keep(features1), keep(matches1), frames[~frames.sequence.isin(reuse)]


if __name__ == "__main__":
    stage_main("features", run)
