"""The environment's episodes: the route windows of a split, and the config they come from.

- `validation`, `test`: evaluate's windows (`evaluate.splits.<split>`: its traversals and window indices), in
  evaluate's order, with evaluate's traversal seeds, window seeds (sensor randomisation, fixed-pattern noise,
  per-frame noise) and warm-up: `expoctl.evaluation.runner.split_windows`.
- `train`: windows of the training city (`world.cities.train`) planned like the validation windows (the validation
  city is the training city under other conditions; `evaluate.splits.validation`'s window kind and lengths, every
  window of a traversal) over traversals 0 … `train_traversals` − 1, under the label `bench-train`, which seeds the
  traversals (speed, sun, sky) and windows: disjoint from evaluate's (`validation`, `test`), select_model's
  (`select`) and collect's seeds (`traversal`, `sequence`), so an agent never trains on a window it is scored on.

Windows are planned one traversal at a time (a traversal's trajectory takes a moment to compute), when an episode
first needs one; every traversal of a city has the same number of windows.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Mapping

from expoctl.bench.errors import EnvArgumentError
from expoctl.errors import InputError
from expoctl.evaluation.config import ROUTE_SPLITS, SplitPlan
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.evaluation.runner import Window, city_windows, split_windows

SPLITS = ("train",) + ROUTE_SPLITS
#: the route split label of training episodes: seeds their traversals and windows (module doc)
TRAIN_LABEL = "bench-train"


def load_inputs(config: str | Path | Mapping | None, scale: str, render_size, project_root) -> tuple[
        EvaluationInputs, Path]:
    """(EvaluationInputs, project root) of the environment: `config` a resolved config file (a project's
    configs/resolved.yaml; its project root, for a relative world.city_dir, is the folder above configs/ unless
    `project_root` is given) or mapping; None: the packaged benchmark config at `scale` (no checkout needed).
    `render_size` (width, height) replaces evaluate.render_size (None: keep the config's)."""
    import yaml

    from expoctl.bench.config import SCALES, packaged_config_text, read_config_file

    if config is None:
        if scale not in SCALES:
            raise EnvArgumentError(f"scale: must be one of {', '.join(SCALES)}, got {scale!r}")
        cfg, root = yaml.safe_load(packaged_config_text(scale)), Path(project_root or ".")
    elif isinstance(config, Mapping):
        cfg, root = dict(config), Path(project_root or ".")
    elif isinstance(config, (str, Path)):
        path = Path(config)
        try:
            cfg = read_config_file(path)
        except InputError as exc:
            raise EnvArgumentError(f"config: {exc}") from None
        root = Path(project_root) if project_root is not None else path.resolve().parent.parent
    else:
        raise EnvArgumentError(f"config: must be a path to a resolved config, a mapping or None, got "
                               f"{type(config).__name__}")
    try:
        inputs = EvaluationInputs.from_resolved(cfg)
    except InputError as exc:  # every problem of the config, each naming its key
        raise EnvArgumentError(f"config: {exc}") from None
    if render_size is not None:
        if not (isinstance(render_size, (list, tuple)) and len(render_size) == 2 and all(
                isinstance(v, int) and not isinstance(v, bool) and 16 <= v <= 8192 for v in render_size)):
            raise EnvArgumentError(f"render_size: must be (width, height) in pixels, 16–8192, got {render_size!r}")
        evaluate = dataclasses.replace(inputs.evaluate, render_size=(int(render_size[0]), int(render_size[1])))
        inputs = dataclasses.replace(inputs, evaluate=evaluate)
    return inputs, root


class Episodes:
    """The windows of one split, indexed 0 … len − 1 in plan order (traversal, then window in route order)."""

    def __init__(self, inputs: EvaluationInputs, project_root: Path, split: str, train_traversals: int):
        if split not in SPLITS:
            raise EnvArgumentError(f"split: must be one of {', '.join(SPLITS)}, got {split!r}")
        if not (isinstance(train_traversals, int) and not isinstance(train_traversals, bool)
                and train_traversals >= 1):
            raise EnvArgumentError(f"train_traversals: must be an integer >= 1, got {train_traversals!r}")
        self.inputs, self.root, self.split = inputs, project_root, split
        plans = inputs.evaluate.splits
        if split == "train":
            template = plans.get("validation") or plans.get("test") or SplitPlan("validation")
            self.plan = dataclasses.replace(template, name="train", first_traversal=0,
                                            n_traversals=train_traversals, windows=None)
        elif split in plans:
            self.plan = plans[split]
        else:
            raise EnvArgumentError(f"split: {split!r} has no plan in this config (evaluate.splits has "
                                   f"{', '.join(plans) or 'none'})")
        self._by_traversal: dict[int, list[Window]] = {}
        self.per_traversal = len(self._traversal(self.plan.first_traversal))

    def __len__(self) -> int:
        return self.plan.n_traversals * self.per_traversal

    def __getitem__(self, i: int) -> Window:
        if not 0 <= i < len(self):
            raise IndexError(f"window {i} of split {self.split!r}: it has {len(self)} (0 … {len(self) - 1})")
        windows = self._traversal(self.plan.first_traversal + i // self.per_traversal)
        return windows[i % self.per_traversal]

    def _traversal(self, index: int) -> list[Window]:
        if index not in self._by_traversal:
            one = dataclasses.replace(self.plan, first_traversal=index, n_traversals=1)
            if self.split == "train":
                fps, warmup = self.inputs.rig.fps, self.inputs.evaluate.warmup_frames
                windows = city_windows(self.inputs, self.root, TRAIN_LABEL, "train", one, "the bench train plan",
                                       fps, warmup)
            else:
                windows = split_windows(self.inputs, self.root, self.split, one)
            if len(self._by_traversal) >= 8:  # a long training run visits many traversals: keep a few
                self._by_traversal.pop(next(iter(self._by_traversal)))
            self._by_traversal[index] = windows
        return self._by_traversal[index]


def describe(w: Window) -> dict[str, Any]:
    """A window as plain values (info["episode"], docs)."""
    return {"sequence": w.sequence, "split": w.route_split, "city": w.city_name, "traversal": w.traversal,
            "window": w.index, "label": w.label, "start": w.start, "stop": w.stop}
