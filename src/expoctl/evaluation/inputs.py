"""What closed-loop evaluation reads from the resolved config, checked and typed once by the stage (evaluate,
select_model) and handed to every run's worker process as is: no worker parses the config again.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from expoctl.camera.sensor import SensorConfig
from expoctl.config_reader import Problems, Section, read_seed
from expoctl.evaluation.config import EvaluateConfig
from expoctl.features.pipeline import FeaturesConfig
from expoctl.sim.closed_loop import RigConfig
from expoctl.world.city import WorldConfig
from expoctl.world.render_config import RenderConfig


def read_controller_configs(sections: Section, names) -> dict[str, Any]:
    """{name: typed config} for each controller of `names` and each registered one with a section under
    `controllers` (every section is checked, whether evaluate drives it or not); a section whose name is no
    registered controller is a problem naming it (an uninstalled plugin, a typo)."""
    from expoctl.controllers.registry import CONTROLLERS

    out = {}
    for name in list(names) + [n for n in sections.mapping if n not in names]:
        if name not in CONTROLLERS:
            for key, problem in CONTROLLERS.problems([name], sections.path(name)):
                sections.problems.add(key, problem)
            continue
        sub = sections.section(name)
        out[name] = sub.read(CONTROLLERS.get(name).config)
        sub.done()
    sections.done(list(sections.mapping))
    return out


@dataclass(frozen=True)
class EvaluationInputs:
    """The `evaluate`, `features`, `world`, `rig`, `sensor` and `controllers` groups, `seed`, and the two paths
    evaluation reads (`paths.frames`: SumLog is tuned on the training frames; the learned controller's network)."""

    evaluate: EvaluateConfig
    features: FeaturesConfig
    seed: int
    world: WorldConfig
    rig: RigConfig
    sensor: SensorConfig
    controllers: dict[str, Any]  # controllers.<name> as its typed config, for every controller evaluate drives
    frames_path: str  # paths.frames
    model_path: str  # controllers.learned.checkpoint, else paths.model (relative: to the project root)

    @classmethod
    def from_resolved(cls, cfg: dict[str, Any], problems: Problems | None = None) -> "EvaluationInputs":
        """Build from the resolved config; every problem of the groups read here is reported at once (with
        `problems`, added to them for the caller to raise with its own)."""
        owner = problems is None
        problems = problems if problems is not None else Problems()
        top = Section(cfg, "", problems)
        evaluate = EvaluateConfig.from_dict(top.value("evaluate", None), "evaluate", problems)
        features = FeaturesConfig.from_dict(top.value("features", None), "features", problems)
        seed = read_seed(top)
        world = WorldConfig.from_dict(top.value("world", None), "world", problems)
        rig = RigConfig.from_dict(top.value("rig", None), "rig", problems)
        sensor = SensorConfig.from_dict(top.value("sensor", None), "sensor", problems)
        controllers = read_controller_configs(top.section("controllers"), evaluate.controllers)
        paths = top.section("paths")
        frames_path = paths.text("frames", "")
        learned = controllers.get("learned")
        model_path = getattr(learned, "checkpoint", None) or paths.text("model", "")
        if owner:
            problems.raise_if_any()
        return cls(evaluate, features, seed, world, rig, sensor, controllers, frames_path, str(model_path))

    @property
    def render(self) -> RenderConfig:
        """The renderer of every run: world.render at evaluate.render_size when that is set, sharing one sharp render
        per frame as evaluate.share_render says."""
        render = replace(self.world.render, share_render=self.evaluate.share_render)
        if self.evaluate.render_size is None:
            return render
        return render.with_size(*self.evaluate.render_size)

    def controller_config(self, name: str) -> Any:
        """The typed config of controller `name` (`controllers.<name>`, read once by `from_resolved`; a registered
        controller the config has no section for: its defaults)."""
        if name in self.controllers:
            return self.controllers[name]
        from expoctl.controllers.registry import controller

        return controller(name).config()

    def frontend_config(self, name: str) -> Any:
        """The typed config of front end `name` (`features.<name>`)."""
        return self.features.config(name)

    def learned_model_path(self, project_root: str | Path) -> Path:
        p = Path(self.model_path)
        return p if p.is_absolute() else Path(project_root) / p
