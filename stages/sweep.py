"""Random hyperparameter search over the train stage: a Hydra multirun app, one job per trial.

    python -m stages.sweep scale=default 'sweep.trial=range(20)'          # 20 trials on this machine
    python -m stages.sweep scale=fixture 'sweep.trial=range(2)' train.epochs=3

Why not hydra-optuna-sweeper: its last release pins optuna < 3, and the project pins optuna 5.0.0. Random search
needs no shared optimiser state, so each Hydra job draws its own values with optuna 5's `RandomSampler` seeded by
(sweep.seed, trial number): Hydra's plain basic sweeper enumerates the trial numbers, any Hydra launcher runs them
(in-process, joblib, or submitit on SLURM), and trial k gets the same hyperparameters wherever it runs.

What a sweep writes: MLflow only — a parent run `sweep <time>` in experiment `sweep.experiment`, one child run per
trial (sampled values, the applied overrides, per-epoch metrics, final validation metrics and the constant-predictor
baseline), and on the parent the best trial's values, `best_objective` and `best.yaml`. Hydra's own job logs go to
`sweeps/<time>/` (git-ignored); no checkpoint is saved and nothing under data/, models/ or reports/ is touched.
Each trial early-stops on its own ε-weighted validation loss; trials are ranked by the validation L1 at one fixed
weighting, `sweep.objective_epsilon` (0.5, the paper's), since the sampled ε changes the loss. The test split is
never used. `best.yaml` lists the winning Hydra overrides — paste them into params.yaml `overrides` and
`dvc repro` to train the pipeline's model with them.

On a SLURM cluster (pip install hydra-submitit-launcher==1.2.0; MLflow on a tracking server reachable from the
nodes — SQLite on a network filesystem does not take concurrent writers):

    MLFLOW_TRACKING_URI=http://mlflow-host:5000 python -m stages.sweep scale=paper 'sweep.trial=range(64)' \
        hydra/launcher=submitit_slurm hydra.launcher.partition=<partition> hydra.launcher.cpus_per_task=8 \
        hydra.launcher.mem_gb=32 hydra.launcher.timeout_min=240 train.num_threads=8

Each trial becomes one SLURM job (submitit pickles it, the sweep dir must be on a shared filesystem); the parent
run is opened before submission and closed, with the best trial, when every job has returned.
"""

from __future__ import annotations

import copy
import json
import logging
import math
import sys
from pathlib import Path

import yaml

from expoctl.errors import ConfigError, InputError

log = logging.getLogger("expoctl.sweep")
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"
PARENT_FILE = "parent_run_id"
_SETS_CACHE: dict = {}


def sample_trial(space: dict, seed: int, trial: int) -> dict:
    """Draw one trial's values from `space` with optuna's RandomSampler (reproducible per (seed, trial))."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="minimize", sampler=optuna.samplers.RandomSampler(seed=seed * 100_003 + trial))
    t = study.ask()
    out = {}
    for key, spec in space.items():
        kind = spec.get("type") if isinstance(spec, dict) else None
        try:
            if kind == "float":
                out[key] = t.suggest_float(key, float(spec["low"]), float(spec["high"]), log=bool(spec.get("log")))
            elif kind == "int":
                out[key] = t.suggest_int(key, int(spec["low"]), int(spec["high"]), log=bool(spec.get("log")))
            elif kind == "categorical":
                out[key] = t.suggest_categorical(key, list(spec["choices"]))
            else:
                raise ConfigError(f"sweep.space.{key}", f"type must be float, int or categorical, got {kind!r}")
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"sweep.space.{key}", f"bad specification {spec!r} ({exc})") from None
    return out


def apply_trial(cfg: dict, values: dict) -> tuple[dict, list[str]]:
    """The config with the trial's values set, and the equivalent Hydra overrides (concrete widths)."""
    from expoctl.net.model import ModelConfig, scale_widths

    cfg = copy.deepcopy(cfg)
    for key, value in values.items():
        if key == "model.width_multiplier":
            continue
        *parents, leaf = key.split(".")
        node = cfg
        for p in parents:
            node = node.get(p) if isinstance(node, dict) else None
        if not isinstance(node, dict) or leaf not in node:
            raise ConfigError(f"sweep.space.{key}", "is not a key of the composed config")
        node[leaf] = value
    overrides = [f"{k}={v}" for k, v in values.items() if k != "model.width_multiplier"]
    if "model.width_multiplier" in values:
        scaled = scale_widths(ModelConfig.from_dict(cfg["model"]), float(values["model.width_multiplier"]))
        cfg["model"]["conv_widths"] = list(scaled.conv_widths)
        cfg["model"]["fc_widths"] = list(scaled.fc_widths)
        overrides += [f"model.conv_widths=[{','.join(map(str, scaled.conv_widths))}]",
                      f"model.fc_widths=[{','.join(map(str, scaled.fc_widths))}]"]
    return cfg, overrides


def run_trial(cfg: dict, sweep: dict, parent_run_id: str | None) -> float:
    """Train one trial as a child MLflow run; returns the objective (inf when the sampled config is invalid)."""
    import mlflow

    from expoctl.host import host_cpu
    from stages.tracking import flatten, git_commit, init_tracking
    from stages.train import configs, train_from_config

    values = sample_trial(sweep["space"], int(sweep["seed"]), int(sweep["trial"]))
    experiment_id = init_tracking(sweep["experiment"])
    with mlflow.start_run(experiment_id=experiment_id, run_name=f"trial_{sweep['trial']}",
                          parent_run_id=parent_run_id,
                          tags={"stage": "sweep_trial", "git_commit": git_commit(), "host_cpu": host_cpu()}):
        mlflow.log_params({"trial": sweep["trial"], **{f"sampled.{k}": v for k, v in values.items()}})
        try:
            trial_cfg, overrides = apply_trial(cfg, values)
            configs(trial_cfg)
        except InputError as exc:
            mlflow.set_tag("error", str(exc))
            mlflow.end_run("FAILED")
            log.warning("trial %s: %s", sweep["trial"], exc)
            return math.inf
        mlflow.log_params({"overrides": json.dumps(overrides),
                           **{k: str(v) for k, v in flatten({"model": trial_cfg["model"],
                                                             "train": trial_cfg["train"]}).items()}})
        key = (json.dumps(trial_cfg["paths"], sort_keys=True), json.dumps(trial_cfg["model"].get("input_size")),
               str(trial_cfg["model"].get("exposure_scale")))
        result, sets, _ = train_from_config(trial_cfg, sets=_SETS_CACHE.get(key),
                                            on_epoch=lambda e, m: mlflow.log_metrics(m, step=e))
        _SETS_CACHE.clear()
        _SETS_CACHE[key] = sets  # keep one dataset in memory across in-process trials
        m = result.metrics
        # Trials may train with different ε, so they are compared on one fixed loss weighting.
        eps = float(sweep["objective_epsilon"])
        objective = eps * m["val_gain_mae_norm"] + (1 - eps) * m["val_exposure_mae_norm"]
        baseline = eps * m["baseline_val_gain_mae_norm"] + (1 - eps) * m["baseline_val_exposure_mae_norm"]
        mlflow.log_metrics({f"final.{k}": float(v) for k, v in m.items()})
        mlflow.log_metrics({"objective": objective, "baseline_objective": baseline})
        log.info("trial %s: objective %.4f (constant predictor %.4f) %s", sweep["trial"], objective, baseline,
                 " ".join(overrides))
        return float(objective)


def _sweep_callback_base():
    from hydra.experimental.callback import Callback

    return Callback


class SweepParentRun(_sweep_callback_base()):
    """Hydra callback: opens the parent MLflow run before the jobs, reports the best trial after them."""

    def on_multirun_start(self, config, **kwargs) -> None:
        from mlflow.tracking import MlflowClient

        from stages.tracking import git_commit, init_tracking, tracking_uri

        sweep_dir = Path(config.hydra.sweep.dir)
        sweep_dir.mkdir(parents=True, exist_ok=True)
        experiment_id = init_tracking(config.sweep.experiment)
        client = MlflowClient(tracking_uri())
        run = client.create_run(experiment_id, run_name=f"sweep {sweep_dir.name}",
                                tags={"stage": "sweep", "git_commit": git_commit(), "sweep_dir": str(sweep_dir)})
        client.log_param(run.info.run_id, "seed", config.sweep.seed)
        client.log_param(run.info.run_id, "space", json.dumps(_plain(config.sweep.space), sort_keys=True)[:6000])
        client.log_param(run.info.run_id, "command_overrides", json.dumps(list(config.hydra.overrides.task))[:6000])
        (sweep_dir / PARENT_FILE).write_text(run.info.run_id)

    def on_multirun_end(self, config, **kwargs) -> None:
        from mlflow.tracking import MlflowClient

        from stages.tracking import tracking_uri

        sweep_dir = Path(config.hydra.sweep.dir)
        parent_id = (sweep_dir / PARENT_FILE).read_text().strip()
        client = MlflowClient(tracking_uri())
        parent = client.get_run(parent_id)
        children = client.search_runs([parent.info.experiment_id], f"tags.mlflow.parentRunId = '{parent_id}'",
                                      max_results=10_000)
        done = [r for r in children if math.isfinite(r.data.metrics.get("objective", math.inf))]
        client.log_metric(parent_id, "n_trials", len(children))
        client.log_metric(parent_id, "n_trials_finished", len(done))
        if not done:
            client.set_terminated(parent_id, "FAILED")
            print(f"sweep {sweep_dir}: no trial finished", file=sys.stderr)
            return
        best = min(done, key=lambda r: r.data.metrics["objective"])
        report = {
            "parent_run_id": parent_id,
            "best_trial": int(best.data.params["trial"]),
            "best_run_id": best.info.run_id,
            "best_objective": best.data.metrics["objective"],
            "baseline_objective": best.data.metrics["baseline_objective"],
            "val_gain_mae_db": best.data.metrics.get("final.val_gain_mae_db"),
            "val_exposure_mae_ev": best.data.metrics.get("final.val_exposure_mae_ev"),
            "overrides": json.loads(best.data.params["overrides"]),
            "n_trials": len(children),
            "n_trials_finished": len(done),
        }
        (sweep_dir / "best.yaml").write_text(yaml.safe_dump(report, sort_keys=False))
        client.log_artifact(parent_id, str(sweep_dir / "best.yaml"))
        client.log_metric(parent_id, "best_objective", report["best_objective"])
        client.log_param(parent_id, "best_trial", report["best_trial"])
        for o in report["overrides"]:
            k, v = o.split("=", 1)
            client.log_param(parent_id, f"best.{k}", v)
        client.set_terminated(parent_id, "FINISHED")
        print(f"best of {len(done)} trials: trial {report['best_trial']}, validation objective "
              f"{report['best_objective']:.4f} (constant predictor {report['baseline_objective']:.4f})\n"
              f"overrides: {' '.join(report['overrides'])}\nreport: {sweep_dir / 'best.yaml'}")


def _plain(node):
    from omegaconf import OmegaConf

    return OmegaConf.to_container(node, resolve=True)


def _trial_task(cfg) -> float:
    from hydra.core.hydra_config import HydraConfig

    c = _plain(cfg)
    sweep = c.pop("sweep")
    parent_file = Path(HydraConfig.get().sweep.dir) / PARENT_FILE
    parent_id = parent_file.read_text().strip() if parent_file.exists() else None
    try:
        return run_trial(c, sweep, parent_id)
    except InputError as exc:  # bad data or config: one line, no traceback
        print(f"expoctl sweep: error: {exc}", file=sys.stderr)
        sys.exit(2)


def _argv_with_defaults(argv: list[str]) -> list[str]:
    """Always multirun; add the sweep config group unless the command line or conf/config.yaml selects it."""
    argv = list(argv)
    defaults = (yaml.safe_load((CONF_DIR / "config.yaml").read_text()) or {}).get("defaults", [])
    in_defaults = any(isinstance(d, dict) and "sweep" in d for d in defaults)
    if not in_defaults and not any(a.lstrip("+~").startswith("sweep=") for a in argv):
        argv.append("+sweep=default")
    if "-m" not in argv and "--multirun" not in argv:
        argv.insert(0, "--multirun")
    return argv


def main() -> None:
    import hydra

    logging.basicConfig(level=logging.INFO, format="[sweep] %(message)s")
    logging.getLogger("alembic").setLevel(logging.WARNING)
    sys.argv = [sys.argv[0], *_argv_with_defaults(sys.argv[1:])]
    hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")(_trial_task)()


if __name__ == "__main__":
    main()
