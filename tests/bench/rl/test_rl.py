"""The RL baseline at fixture scale: SAC trains a few hundred steps, checkpoints, resumes from the saved step count,
and the `rl` controller built from the folder reproduces the environment's observation and the policy's action, and
is scored by `expoctl bench`'s plan (evaluate's closed loop) beside a baseline."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from expoctl.errors import InputError
from expoctl.bench.rl.config import read_rl_config

SMALL = {"learning_starts": 40, "batch_size": 16, "checkpoint_every": 60, "log_every": 20,
         "render_size": [80, 60], "obs_size": [40, 30], "buffer_size": 1000, "train_traversals": 2}


@pytest.fixture(scope="module")
def agent(tmp_path_factory):
    from expoctl.bench.rl.train import train

    folder = tmp_path_factory.mktemp("proj") / "models" / "rl"
    logged = []
    first = train(read_rl_config({**SMALL, "total_steps": 120}), folder, scale="fixture",
                  log_metrics=lambda m, step: logged.append((step, m)))
    saved = json.loads((folder / "agent.json").read_text())["steps"]
    second = train(read_rl_config({**SMALL, "total_steps": 200}), folder, scale="fixture")
    return folder, first, saved, second, logged


def test_trains_checkpoints_and_resumes(agent):
    folder, first, saved, second, logged = agent
    assert first["steps"] == saved == 120 and first["resumed_from"] == 0
    assert second["resumed_from"] == 120 and second["steps"] == 200 and second["steps_this_run"] == 80
    assert (folder / "agent.zip").is_file() and (folder / "replay_buffer.pkl").is_file()
    assert json.loads((folder / "agent.json").read_text())["steps"] == 200
    assert any("episode_reward" in m for _, m in logged) and any("steps_per_s" in m for _, m in logged)


def test_resume_refuses_other_settings(agent):
    from expoctl.bench.rl.train import train

    with pytest.raises(InputError, match=r"rl\.gamma"):
        train(read_rl_config({**SMALL, "total_steps": 300, "gamma": 0.5}), agent[0], scale="fixture")


def test_controller_acts_as_the_policy_in_the_env(agent):
    """The controller, given the full-size frame, builds the env's observation and takes the policy's action."""
    from expoctl.bench.env import ExposureEnv
    from expoctl.controllers.base import Settings
    from expoctl.bench.rl.controller import RLController
    from expoctl.bench.rl.agent import feature_env

    cfg = read_rl_config({**SMALL, "total_steps": 200})
    ctrl = RLController.from_folder(agent[0])
    env = feature_env(ExposureEnv("validation", scale="fixture", render_mode="rgb_array", **cfg.env_kwargs()),
                      cfg.histogram_bins, cfg.exposure_scale)
    obs, info = env.reset(options={"window": 0})
    actions = set()
    for _ in range(25):
        applied = Settings(info["settings"]["gain_db"], info["settings"]["exposure_us"])
        want, _ = ctrl.model.predict(obs, deterministic=True)
        got = ctrl.action(env.render(), applied)
        np.testing.assert_array_equal(got, want)
        command = ctrl.update(env.render(), applied)
        obs, _, done, _, info = env.step(got)
        # the env applied exactly the controller's command to the next frame
        assert Settings(info["settings"]["gain_db"], info["settings"]["exposure_us"]) == command.clamped()
        actions.add(float(got[0]))
        if done:
            break
    assert len(actions) > 1  # the policy responds to what it sees


def test_bench_scores_rl_when_trained_and_skips_it_when_not(agent, tmp_path):
    from expoctl.bench.config import packaged_config_text
    from expoctl.bench.score import plan_benchmark, run_benchmark
    from expoctl.bench.rl.controller import with_rl

    cfg = yaml.safe_load(packaged_config_text("fixture"))
    root = agent[0].parent.parent
    plan = plan_benchmark(cfg, root, baselines=("fixed", "rl"))
    assert "rl" in plan.controllers and "rl" not in plan.skipped
    out = run_benchmark(plan, root)
    for split in out.result.metrics:
        assert "rl" in out.result.metrics[split] and "fixed" in out.result.metrics[split]
    # no agent: a default list skips it with the reason, an explicit one is an error naming the folder
    empty = plan_benchmark(cfg, tmp_path, baselines=("fixed", "rl"))
    assert "rl" not in empty.controllers and "no trained agent" in empty.skipped["rl"]
    assert with_rl({**cfg, "evaluate": {**cfg["evaluate"], "controllers": None}}, tmp_path)[1]
    with pytest.raises(InputError, match="controller 'rl' is listed"):
        with_rl({**cfg, "evaluate": {**cfg["evaluate"], "controllers": ["fixed", "rl"]}}, tmp_path)


def test_train_rl_stage_off_writes_only_its_marker(tmp_path):
    from stages.compose import compose_config
    from stages.train_rl import run

    class Tracker:
        def log_metrics(self, *a, **k):
            raise AssertionError("an off stage logs no metrics")

    cfg = compose_config(["scale=fixture"])
    assert cfg["rl"]["enabled"] is False
    (tmp_path / "models" / "rl").mkdir(parents=True)
    (tmp_path / "models" / "rl" / "agent.zip").write_bytes(b"stale")
    run(cfg, Tracker(), project_root=tmp_path)
    assert sorted(p.name for p in (tmp_path / "models" / "rl").iterdir()) == ["DISABLED.json"]
    with pytest.raises(InputError, match="train_rl stage is off"):
        from expoctl.bench.rl.controller import RLController

        RLController.from_folder(tmp_path / "models" / "rl")
