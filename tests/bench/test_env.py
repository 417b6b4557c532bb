"""The benchmark environment (expoctl.bench.env) at fixture size: gymnasium's checker, vector envs, exact seeding,
the action modes' latency and semantics, the reward, info, training episodes, and clear errors for bad arguments."""

from __future__ import annotations

import functools
import math

import gymnasium as gym
import numpy as np
import yaml
import pytest
from gymnasium.utils.env_checker import check_env

import expoctl.bench  # noqa: F401  (registers expoctl/Exposure-v0)
from expoctl.bench.env import ExposureEnv
from expoctl.bench.episodes import TRAIN_LABEL
from expoctl.controllers.agae import ln_exposure_product
from expoctl.controllers.base import Settings
from expoctl.evaluation.runner import plan_windows

ENV_ID = "expoctl/Exposure-v0"


def _env(**kw) -> ExposureEnv:
    return ExposureEnv(kw.pop("split", "validation"), scale="fixture", **kw)


def test_gymnasium_checker_passes():
    env = gym.make(ENV_ID, split="validation", scale="fixture")
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_module_id_form_makes_the_env():
    env = gym.make("expoctl.bench:expoctl/Exposure-v0", split="test", scale="fixture", action="ev_step")
    assert isinstance(env.unwrapped, ExposureEnv) and env.action_space.shape == (1,)


def _rollout(env, seed, n=6, action_seed=1):
    rng = np.random.default_rng(action_seed)
    obs, info = env.reset(seed=seed)
    out = [(obs["image"].copy(), obs["settings"].copy(), info["sequence"], None)]
    for _ in range(n):
        a = rng.uniform(env.action_space.low, env.action_space.high)
        obs, reward, term, _, info = env.step(a)
        out.append((obs["image"].copy(), obs["settings"].copy(), info["sequence"], reward))
        if term:
            break
    return out


def _same(a, b) -> bool:
    return all(np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1]) and x[2:] == y[2:] for x, y in zip(a, b))


def test_seeding_is_exact_and_picks_the_window():
    first = _rollout(_env(split="train", train_traversals=4), seed=3)
    again = _rollout(_env(split="train", train_traversals=4), seed=3)
    assert len(first) == len(again) and _same(first, again)  # a fresh env, the same seed: the same episode
    env = _env(split="train", train_traversals=4)
    drawn = {env.reset(seed=s)[1]["sequence"] for s in range(6)}
    assert len(drawn) > 1  # the seed picks the window
    other_actions = _rollout(_env(split="train", train_traversals=4), seed=3, action_seed=2)
    assert not _same(first, other_actions)  # the actions matter (the comparison can fail)


def test_vector_envs_sync_and_async_agree():
    # a picklable maker with the module:id form (a spawned worker imports expoctl.bench for the id); spawn, since
    # fork is unsafe once numba's GNU OpenMP pool has rendered in this process
    make = functools.partial(gym.make, "expoctl.bench:" + ENV_ID, split="validation", scale="fixture",
                             obs_size=(40, 30))
    actions = np.tile(np.array([[0.1, 0.5]]), (2, 1))
    results = []
    for cls, kw in ((gym.vector.SyncVectorEnv, {}), (gym.vector.AsyncVectorEnv, {"context": "spawn"})):
        venv = cls([make, make], **kw)
        obs, infos = venv.reset(seed=5)
        assert obs["image"].shape == (2, 30, 40, 3) and obs["image"].dtype == np.uint8
        steps = [venv.step(actions) for _ in range(3)]
        results.append((obs["image"], [s[0]["image"] for s in steps], [s[1] for s in steps]))
        venv.close()
    (o1, i1, r1), (o2, i2, r2) = results
    assert np.array_equal(o1, o2) and all(np.array_equal(a, b) for a, b in zip(i1, i2))
    assert all(np.array_equal(a, b) for a, b in zip(r1, r2))


def test_one_frame_latency_and_the_episode():
    env = _env(action="settings")
    obs, info = env.reset(options={"window": 0})
    w = env.window
    assert info["warmup"] and info["frame"] == -env.inputs.evaluate.warmup_frames
    assert tuple(obs["settings"]) == (0.0, 5000.0) and math.isnan(info["nfm"]["orb"])
    obs, reward, term, trunc, info = env.step([6.0, 1234.5])
    assert tuple(obs["settings"]) == (6.0, 1234.5)  # the action set the next frame, the one this step delivers
    assert reward == info["nfm"]["orb"] >= 0 and not (term or trunc)
    obs, *_ = env.step([40.0, 1.0])  # outside the space: clipped, then clamped to the camera's range
    assert tuple(obs["settings"]) == (30.0, 19.0)
    n = 2
    while not term:
        obs, reward, term, trunc, info = env.step([0.0, 2000.0])
        n += 1
    assert info["traj_frame"] == w.stop - 1 and not info["warmup"] and info["frame"] == w.stop - w.start - 1
    assert n == w.stop - w.start + env.inputs.evaluate.warmup_frames - 1
    assert set(info) >= {"settings", "nfm", "clipped_share", "timestamp_ns", "frame", "warmup", "section"}
    with pytest.raises(RuntimeError, match="reset"):
        env.step([0.0, 2000.0])


def test_absolute_and_ev_step_actions():
    env = _env(action="absolute", exposure_scale="log")
    env.reset(options={"window": 0})
    obs, *_ = env.step([0.5, 1.0])
    assert obs["settings"][0] == 15.0 and obs["settings"][1] == pytest.approx(30000.0, rel=1e-12)
    obs, *_ = env.step([0.0, 0.0])  # log scale: 0 is the network's shortest exposure, 75 µs
    assert obs["settings"][1] == pytest.approx(75.0, rel=1e-12)
    assert env.action_space.low[1] < 0  # … and the axis reaches down to the sensor's 19 µs
    ev = _env(action="ev_step", max_ev_step=0.5)
    obs, _ = ev.reset(options={"window": 0})
    before = ln_exposure_product(ev.actions.settings_of([0.0], Settings(*obs["settings"])))
    obs, *_ = ev.step([3.0])  # clipped to +0.5 EV, spent on exposure first: gain stays 0 dB
    assert obs["settings"][0] == 0.0
    assert (ln_exposure_product(Settings(*obs["settings"])) - before) / math.log(2) == pytest.approx(0.5)


def test_clipped_penalty_and_reward_scale():
    plain = _env(action="settings")
    scaled = _env(action="settings", reward_scale=0.01, clipped_penalty=2.0)
    for env in (plain, scaled):
        env.reset(options={"window": 0})
    (_, r0, *_, i0), (_, r1, *_, i1) = plain.step([30.0, 30000.0]), scaled.step([30.0, 30000.0])
    assert i0["clipped_share"] == i1["clipped_share"] > 0.5  # overexposed
    assert r1 == pytest.approx(0.01 * r0 - 2.0 * i1["clipped_share"])


def test_train_episodes_are_the_train_city_with_their_own_seeds():
    env = _env(split="train", train_traversals=3)
    assert len(env.episodes) == 3 * env.episodes.per_traversal
    train = [env.episodes[i] for i in range(len(env.episodes))]
    assert {w.route_split for w in train} == {TRAIN_LABEL} and {w.traversal for w in train} == {0, 1, 2}
    assert train[0].city_name == "train"
    evaluated = plan_windows(env.inputs)
    assert not {w.seed for w in train} & {w.seed for w in evaluated}
    assert not {w.traversal_seed for w in train} & {w.traversal_seed for w in evaluated}


def test_obs_size_resizes_only_the_observation():
    env = _env(obs_size=(32, 24), render_mode="rgb_array")
    obs, _ = env.reset(seed=0)
    assert obs["image"].shape == (24, 32, 3) and env.observation_space.contains(obs)
    assert env.render().shape == (120, 160, 3)


@pytest.mark.parametrize("kwargs, argument", [
    ({"frontend": "sift"}, "frontend"),
    ({"info_frontends": ["orb", "nope"]}, "info_frontends"),
    ({"split": "holdout"}, "split"),
    ({"action": "relative"}, "action"),
    ({"exposure_scale": "cubic"}, "exposure_scale"),
    ({"max_ev_step": 0}, "max_ev_step"),
    ({"obs_size": (320, 240)}, "obs_size"),
    ({"obs_size": (0, 10)}, "obs_size"),
    ({"render_size": (8, 8)}, "render_size"),
    ({"reward_scale": float("nan")}, "reward_scale"),
    ({"train_traversals": 0}, "train_traversals"),
    ({"scale": "huge", "config": None}, "scale"),
])
def test_bad_arguments_name_the_argument(kwargs, argument):
    split = kwargs.pop("split", "validation")
    with pytest.raises(ValueError, match=f"^{argument}: "):
        ExposureEnv(split, **{"scale": "fixture", **kwargs})


def test_bad_actions_and_options_are_refused():
    env = _env()
    with pytest.raises(ValueError, match="options\\['window'\\]"):
        env.reset(options={"window": 99})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="^action: must be finite"):
        env.step([float("nan"), 0.5])
    with pytest.raises(ValueError, match="^action: must be 2 numbers"):
        env.step([0.5])


def test_a_projects_resolved_config_is_read_from_its_path(tmp_path):
    from expoctl.bench.config import packaged_config_text

    path = tmp_path / "configs" / "resolved.yaml"
    path.parent.mkdir()
    path.write_text(packaged_config_text("fixture").replace("\nseed: 0\n", "\nseed: 7\n"))
    env = ExposureEnv("validation", config=path)
    assert env.episodes.root == tmp_path  # a relative world.city_dir would be under the project
    assert env.inputs.seed == 7 and env.episodes[0].seed != _env().episodes[0].seed  # the file's, not the packaged
    with pytest.raises(ValueError, match="^config: .*no such config file"):
        ExposureEnv("validation", config=tmp_path / "missing.yaml")
    with pytest.raises(ValueError, match="^config: config key 'evaluate.warmup_frames'"):
        ExposureEnv("validation", config={**yaml.safe_load(packaged_config_text("fixture")),
                                          "evaluate": {"warmup_frames": -1, "splits": {"test": {}}}})
