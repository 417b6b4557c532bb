"""evaluate stage: every controller drives the simulated camera → reports/metrics.json, reports/eval/ (expoctl.evaluation).

MLflow: besides the stage run (params, headline metrics, metrics.json), one nested child run per (controller, city)
tagged controller / city / route_split, with that pair's section statistics, tracking success, VO error and timing
as metrics and its timeline figure (NFM and gain/exposure around the portals) as an artifact — so the MLflow UI
compares controllers side by side: the experiment's saved view "Compare controllers" lists the last evaluate run's
child runs flat with the leaderboard metrics as columns (stages/tracking.py set_compare_view, docs/pipeline.md).
"""

from __future__ import annotations

import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from expoctl.bench.rl.controller import with_rl
from expoctl.errors import InputError
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.evaluation.runner import evaluate, metrics_summary, write_outputs
from expoctl.host import host_cpu
from expoctl.net.checkpoint import check_checkpoint
from expoctl.parallel import ParallelConfig
from stages.common import PROJECT_ROOT, stage_main
from stages.tracking import set_compare_view

log = logging.getLogger(__name__)


def final_model_config(cfg: dict) -> dict:
    """The learned controller under evaluation is the pipeline's final model, `paths.final_model`: the network the
    select_model stage chose among the iterations' (stages/select_model.py)."""
    return {**cfg, "paths": {**cfg["paths"], "model": cfg["paths"]["final_model"]}}


def run(cfg: dict, tracker, project_root: Path | None = None) -> None:
    root = Path(project_root or PROJECT_ROOT)
    if "final_model" in cfg.get("paths", {}):
        cfg = final_model_config(cfg)
    # `rl` (opt-in): joins a null controller list only when train_rl made an agent; listed without one, an error
    cfg, rl_skipped = with_rl(cfg, root)
    if rl_skipped:
        log.info("controller rl skipped: %s", rl_skipped)
    inputs = EvaluationInputs.from_resolved(cfg)  # every config problem at once, before any work
    check_network(inputs, root)
    t0 = time.perf_counter()
    result = evaluate(inputs, root, progress=sys.stderr.isatty(), parallel=ParallelConfig.from_resolved(cfg))
    seconds = time.perf_counter() - t0
    out = write_outputs(result, root / cfg["paths"]["reports_dir"])
    if inputs.evaluate.offline_bound.enabled:  # opt-in: off, evaluate's outputs are what they were without it
        write_offline_bound(inputs, result, out["eval_dir"], tracker, ParallelConfig.from_resolved(cfg))
    runs = result.runs
    tracker.log_params({"sumlog": {k: {"alpha": list(v.alpha), "beta": v.beta, "rescale": v.rescale}
                                   for k, v in result.sumlog.items()}})
    tracker.log_metrics({"seconds": seconds, "n_runs": len(runs), "n_windows": len(result.windows),
                         "n_frames": len(result.frames),
                         "frames_per_s": len(result.frames) / max(seconds, 1e-9), **metrics_summary(result.metrics)})
    tracker.log_artifact(out["metrics"])
    log_child_runs(result, tracker)
    for split, ctrls in result.metrics.items():
        for ctrl, e in ctrls.items():
            fe = inputs.evaluate.frontends[0]
            d, t = e["dynamic"][fe], e["tracking_success"]
            log.info("%-10s %-15s dynamic %s median %s min %s; VO %d/%d", split, ctrl, fe, _fmt(d["median_nfm"]),
                     _fmt(d["min_nfm"]), t[0], t[1])
    log.info("%d runs, %d frames in %.0f s → %s", len(runs), len(result.frames), seconds, out["metrics"])


def write_offline_bound(inputs: EvaluationInputs, result, eval_dir: Path, tracker, parallel) -> Path:
    """reports/eval/offline_bound.json: the offline optimum of every evaluated window over the grid
    (expoctl.evaluation.offline_bound, `evaluate.offline_bound`); its aggregate numbers go to MLflow as offline_bound.*."""
    from expoctl.io import write_json
    from expoctl.evaluation.offline_bound import evaluate_bounds

    t0 = time.perf_counter()
    bound = evaluate_bounds(inputs, result.windows, result.sumlog, parallel)
    path = eval_dir / "offline_bound.json"
    write_json(bound, path)
    flat = {f"offline_bound.{split}.{kind}.{v}.{stat}": val for split, kinds in bound["metrics"].items()
            for kind, vs in kinds.items() for v, stats in vs.items() for stat, val in stats.items()}
    tracker.log_metrics({**flat, "offline_bound.seconds": time.perf_counter() - t0})
    log.info("offline bound (%s) over %d windows in %.0f s -> %s", bound["grid"]["label"], len(bound["windows"]),
             time.perf_counter() - t0, path)
    return path


def check_network(inputs: EvaluationInputs, root: Path) -> None:
    """The network the learned controller drives (the final model), checked before any evaluation work: a truncated
    or mismatched checkpoint, or with `controllers.learned.backend: onnx` a bad .onnx beside it, stops the stage at
    once with an InputError naming the file (not minutes later in a worker)."""
    if "learned" not in inputs.evaluate.controllers:
        return
    path = inputs.learned_model_path(root)
    if not path.is_file():
        raise InputError(f"{path}: trained model missing — the 'learned' controller cannot run; run the train and "
                         "select_model stages first (or drop 'learned' from evaluate.controllers)")
    check_checkpoint(path, onnx=inputs.controller_config("learned").backend == "onnx")


def _fmt(v) -> str:
    return "—" if v is None else f"{v:.0f}"


def child_metrics(result, split: str, controller: str) -> dict[str, float]:
    """The metrics of one (controller, city) child run."""
    e = result.metrics[split][controller]
    m: dict[str, float] = {}
    for kind in ("static", "dynamic"):
        for fe, stats in e[kind].items():
            for stat, v in stats.items():
                if v is not None:
                    m[f"{kind}.{fe}.{stat}"] = float(v)
    n_ok, n = e["tracking_success"]
    m.update({"tracking_success_n_ok": n_ok, "tracking_success_n_runs": n, "tracking_success_rate": n_ok / n})
    r = result.runs[(result.runs.route_split == split) & (result.runs.controller == controller)]
    if "vo_map_success" in r.columns and len(r):
        n_map = int(r.vo_map_success.astype(bool).sum())
        m.update({"tracking_map_success_n_ok": n_map, "tracking_map_success_rate": n_map / len(r)})
    for col in ("vo_ate_m", "vo_rpe_trans_m", "vo_rpe_rot_deg", "controller_ms_median", "seconds_per_frame"):
        vals = r[col].to_numpy(dtype=float)
        vals = vals[np.isfinite(vals)]
        if len(vals):
            m[f"{col}_mean"] = float(vals.mean())
    return m


def log_child_runs(result, tracker) -> list[str]:
    """One nested MLflow run per (controller, city) under the active stage run; returns their run ids."""
    import mlflow

    from expoctl.report.figures import controller_timeline

    if mlflow.active_run() is None:  # a fake tracker in tests: nothing to nest under
        return []
    active = mlflow.active_run()
    parent, experiment_id = active.info.run_id, active.info.experiment_id
    ids = []
    host = host_cpu()  # as on the stage run: the children carry per-frame timings and are searched on their own
    with tempfile.TemporaryDirectory() as tmp:
        for split, ctrls in result.metrics.items():
            city = str(result.runs[result.runs.route_split == split]["city"].iloc[0])
            for ctrl in ctrls:
                tags = {"stage": "evaluate", "controller": ctrl, "city": city, "route_split": split,
                        "parent_stage_run": parent, "host_cpu": host}
                with mlflow.start_run(run_name=f"{ctrl} @ {city}", experiment_id=experiment_id, nested=True,
                                      tags=tags) as child:
                    mlflow.log_params({"controller": ctrl, "city": city, "route_split": split})
                    mlflow.log_metrics(child_metrics(result, split, ctrl))
                    fig = Path(tmp) / f"timeline_{split}_{ctrl}.png"
                    if controller_timeline(result.frames, split, ctrl, fig):
                        mlflow.log_artifact(str(fig), artifact_path="figures")
                    ids.append(child.info.run_id)
    # the UI folds these under the stage run; its saved view lists this run's controllers flat, metrics as columns
    view = set_compare_view(experiment_id, evaluate_run=parent)
    log.info("MLflow: this evaluation's controllers side by side at <mlflow ui>/%s", view)
    return ids


if __name__ == "__main__":
    stage_main("evaluate", run)
