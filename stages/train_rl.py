"""train_rl stage (optional, off by default): the reinforcement-learning baseline → models/rl (expoctl.bench.rl.train).

`rl.enabled: false`: writes only models/rl/DISABLED.json (DVC needs its output; evaluate then skips `rl`); its
MLflow run records only the params. On: trains SAC/PPO in expoctl/Exposure-v0 on the training city of the resolved config, resuming from
models/rl when it holds a checkpoint of the same settings (raise rl.total_steps to continue), with its own MLflow
run: the rl keys as params, episode reward and NFM per episode and reward/steps-per-s every rl.log_every steps as
metrics at their env step, agent.json as an artifact.
"""

from __future__ import annotations

import logging
from pathlib import Path

from expoctl.bench.rl.config import read_rl_config
from stages.common import PROJECT_ROOT, stage_main

log = logging.getLogger(__name__)
AGENT_DIR = "models/rl"


def run(cfg: dict, tracker, project_root: Path | None = None) -> None:
    from expoctl.bench.rl.train import train, write_disabled

    root = Path(project_root or PROJECT_ROOT)
    config = read_rl_config(cfg.get("rl"))
    out = root / AGENT_DIR
    if not config.enabled:
        log.info("rl.enabled is false: no agent trained -> %s", write_disabled(out))
        return
    summary = train(config, out, env_config=cfg, project_root=root,
                    log_metrics=lambda metrics, step: tracker.log_metrics(metrics, step=step))
    tracker.log_metrics({f"train.{k}": v for k, v in summary.items()})
    tracker.log_artifact(out / "agent.json")


if __name__ == "__main__":
    stage_main("train_rl", run)
