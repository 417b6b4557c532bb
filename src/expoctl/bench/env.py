"""The closed-loop gain/exposure environment (gymnasium 1.x): `expoctl/Exposure-v0` (docs/benchmark.md).

One episode = one route window of a split (`expoctl.bench.episodes`), simulated exactly as evaluate simulates it
(`expoctl.evaluation.runner.window_sim`: the same scene, sensor randomisation, fixed-pattern and per-frame noise),
from evaluate's initial settings (evaluate.initial_gain_db / initial_exposure_us) through its warm-up
(evaluate.warmup_frames; `info["warmup"]` is true there) to the window's last frame. The agent drives the warm-up,
as a controller does in evaluate.

The loop is the simulator's (`expoctl.sim.closed_loop.run_closed_loop`), with the agent in the controller's place:
`reset` delivers the first frame, captured with the initial settings; `step(action)` sets the settings of the next
frame from the action (one frame of latency: nothing decided from frame t changes frame t), captures it and returns
it. The observation is that frame and the settings it was exposed with; the reward is the inlier matches (NFM)
between it and the frame before, counted as evaluate counts them (`expoctl.evaluation.run.PairMatches`: same front
end, same RANSAC seeds), times `reward_scale`, minus `clipped_penalty` × the frame's clipped share. The episode
terminates when the window's last frame has been delivered; it is never truncated.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from pathlib import Path
from typing import Any, Mapping, Sequence

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from expoctl.bench.actions import ActionMap
from expoctl.bench.episodes import Episodes, describe, load_inputs
from expoctl.bench.errors import EnvArgumentError
from expoctl.camera import ranges
from expoctl.controllers.base import Controller, Settings


def observation(image: np.ndarray, settings: Settings, obs_size: tuple[int, int] | None = None) -> dict[str, Any]:
    """The environment's observation of a frame (H×W×3 uint8 at the render size) exposed with `settings`: the frame,
    INTER_AREA-resized to `obs_size` (width, height) when set, and [gain_db, exposure_us] in float64. One function,
    so that a policy driven outside the environment (the `rl` controller) sees exactly what it was trained on."""
    if obs_size is not None:
        import cv2

        image = cv2.resize(image, obs_size, interpolation=cv2.INTER_AREA)
    return {"image": image, "settings": np.array([settings.gain_db, settings.exposure_us], dtype=np.float64)}


class _Command(Controller):
    """The agent in the closed loop's controller seat: returns the settings the last action chose."""

    name = "agent"

    def __init__(self):
        self.next: Settings | None = None

    def reset(self, initial: Settings) -> None:
        self.next = None

    def update(self, image: np.ndarray, applied: Settings) -> Settings:
        if self.next is None:
            raise RuntimeError("the closed loop asked for the next settings before the agent chose them")
        out, self.next = self.next, None
        return out


class ExposureEnv(gym.Env):
    """Drive camera 1's gain and exposure over one route window per episode; see the module doc and
    docs/benchmark.md for the observation, action and reward contract."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 15}

    def __init__(self, split: str = "train", *, config: str | Path | Mapping | None = None, scale: str = "default",
                 project_root: str | Path | None = None, action: str = "absolute", exposure_scale: str = "log",
                 max_ev_step: float = 1.0, frontend: str = "orb", info_frontends: Sequence[str] | None = None,
                 reward_scale: float = 1.0, clipped_penalty: float = 0.0,
                 render_size: tuple[int, int] | None = None, obs_size: tuple[int, int] | None = None,
                 train_traversals: int = 64, render_mode: str | None = None):
        from expoctl.features.registry import FRONTENDS

        known = FRONTENDS.names()
        if frontend not in known:
            raise EnvArgumentError(f"frontend: unknown front end {frontend!r} (registered: {', '.join(known)})")
        extra = () if info_frontends is None else tuple(info_frontends)
        unknown = [f for f in extra if f not in known]
        if isinstance(info_frontends, str) or unknown:
            raise EnvArgumentError(f"info_frontends: must be a list of registered front ends ({', '.join(known)}), "
                                   f"got {info_frontends!r}")
        for name, value in (("reward_scale", reward_scale), ("clipped_penalty", clipped_penalty)):
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise EnvArgumentError(f"{name}: must be a finite number, got {value!r}")
        if render_mode not in (None, "rgb_array"):
            raise EnvArgumentError(f"render_mode: must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.actions = ActionMap(action, exposure_scale, max_ev_step)
        self.inputs, root = load_inputs(config, scale, render_size, project_root)
        self.episodes = Episodes(self.inputs, root, split, train_traversals)
        self.split, self.frontend = split, frontend
        self.frontends = (frontend,) + tuple(f for f in dict.fromkeys(extra) if f != frontend)
        self.reward_scale, self.clipped_penalty = float(reward_scale), float(clipped_penalty)
        render = self.inputs.render
        self.render_size = (render.width, render.height)
        if obs_size is not None:
            if not (isinstance(obs_size, (list, tuple)) and len(obs_size) == 2 and all(
                    isinstance(v, int) and not isinstance(v, bool) for v in obs_size)
                    and 1 <= obs_size[0] <= render.width and 1 <= obs_size[1] <= render.height):
                raise EnvArgumentError(f"obs_size: must be (width, height) within the {render.width}x{render.height} "
                                       f"render (a downscale for agents), got {obs_size!r}")
            obs_size = (int(obs_size[0]), int(obs_size[1]))
        self.obs_size = obs_size
        w, h = obs_size or self.render_size
        self.observation_space = spaces.Dict({
            "image": spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8),
            "settings": spaces.Box(np.array([ranges.GAIN_DB_MIN, ranges.SENSOR_EXPOSURE_US_MIN]),
                                   np.array([ranges.GAIN_DB_MAX, ranges.EXPOSURE_US_MAX]), dtype=np.float64),
        })
        self.action_space = self.actions.space
        ecfg = self.inputs.evaluate
        self.initial = Settings(ecfg.initial_gain_db, ecfg.initial_exposure_us)
        self._sims: OrderedDict[str, Any] = OrderedDict()
        self._loop = None
        self.window, self.window_index = None, None

    # ----------------------------------------------------------------------------------------------- episodes

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode: `options={"window": i}` drives window i of the split (plan order, evaluate's for
        validation/test); otherwise the window is drawn uniformly from `np_random` (seeded by `seed`)."""
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"window"}
        if unknown:
            raise EnvArgumentError(f"options: unknown key(s) {sorted(unknown)} (known: window)")
        if "window" in options:
            i = options["window"]
            if isinstance(i, bool) or not isinstance(i, (int, np.integer)) or not 0 <= i < len(self.episodes):
                raise EnvArgumentError(f"options['window']: must be an integer in [0, {len(self.episodes)}) for "
                                       f"split {self.split!r}, got {i!r}")
        else:
            i = int(self.np_random.integers(len(self.episodes)))
        self.window_index = int(i)
        self.window = w = self.episodes[self.window_index]
        sim = self._sim(w)
        from expoctl.evaluation.run import PairMatches
        from expoctl.features.pipeline import make_frontend
        from expoctl.sim.closed_loop import run_closed_loop

        self._traj = sim.trajectory
        fcfg = self.inputs.features
        # fresh front ends per episode: a matcher may keep state between frames (as evaluate makes them per run)
        self._matches = PairMatches({f: make_frontend(f, fcfg.config(f)) for f in self.frontends}, w.sequence)
        self._first = max(0, w.start - self.inputs.evaluate.warmup_frames)
        self._command = _Command()
        frames = range(self._first, w.stop)
        self._loop = run_closed_loop(sim.scene, [sim.sensor], self._command, self.initial, frames, w.seed)
        obs, _, info = self._deliver(next(self._loop))
        return obs, info

    def step(self, action):
        if self._loop is None:
            raise RuntimeError("step() before reset(), or after the episode terminated: call reset()")
        self._command.next = self.actions.settings_of(action, self._applied)
        frame = next(self._loop)
        obs, reward, info = self._deliver(frame)
        terminated = frame.frame_index == self.window.stop - 1
        if terminated:
            self._loop = None  # the window's last frame: no command after it is needed
        return obs, reward, terminated, False, info

    def render(self):
        """The last delivered frame at the render size (H×W×3 uint8), for render_mode 'rgb_array'."""
        return None if self.render_mode is None else self._image

    def close(self):
        self._sims.clear()
        self._loop = None

    # ----------------------------------------------------------------------------------------------- helpers

    def action_of(self, settings: Settings) -> np.ndarray:
        """An action that sets the next frame to exactly `settings` from the current frame (ValueError when the
        action mode cannot, `expoctl.bench.actions`)."""
        return self.actions.action_of(settings, self._applied)

    def _sim(self, w):
        from expoctl.evaluation.runner import window_sim

        # a window's simulation is a pure function of (frame, settings): episodes of the same window reuse it
        if w.sequence not in self._sims:
            if len(self._sims) >= 4:
                self._sims.popitem(last=False)
            self._sims[w.sequence] = window_sim(self.inputs, w)
        self._sims.move_to_end(w.sequence)
        return self._sims[w.sequence]

    def _deliver(self, rig_frame):
        """(observation, reward, info) of one frame of the loop."""
        from expoctl.evaluation.run import image_stats
        from expoctl.features.pipeline import rgb_to_grey

        cam = rig_frame.camera(1)
        img, settings = cam.image, cam.settings
        self._applied, self._image = settings, img
        w, t = self.window, rig_frame.frame_index
        k = t - w.start  # the frame's index in the window, as evaluate numbers it (< 0: warm-up)
        grey = rgb_to_grey(img)
        row: dict[str, Any] = {}
        self._matches.record(k, img, grey, row)
        stats = image_stats(grey)
        clipped = stats["saturated_frac"] + stats["dark_frac"]
        nfm = {f: row[f"nfm_{f}"] for f in self.frontends}
        reward = self.reward_scale * nfm[self.frontend] - self.clipped_penalty * clipped
        obs = observation(img, settings, self.obs_size)
        info = {"settings": {"gain_db": settings.gain_db, "exposure_us": settings.exposure_us},
                "nfm": nfm, "nfeat": {f: row[f"nfeat_{f}"] for f in self.frontends},
                "clipped_share": clipped, "saturated_share": stats["saturated_frac"],
                "dark_share": stats["dark_frac"], "mean_grey": stats["mean_grey"],
                "timestamp_ns": int(rig_frame.timestamp_ns), "frame": k, "traj_frame": t, "warmup": k < 0,
                "section": str(self._traj.frame_section[t]), "window": self.window_index, "sequence": w.sequence}
        return obs, float(reward), info
