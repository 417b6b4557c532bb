"""Check a composed config before the compose stage writes configs/resolved.yaml.

Every stage checks its own config groups, but only when it runs: a bad `train.lr` would surface after collect,
ingest, features, labels and samples have run. `check_resolved` builds, in one pass and with one shared `Problems`,
every typed config group any stage reads, with the same readers the stages use, so `dvc repro` stops at compose
with every problem named by its dotted key. It only reads configs (and the city YAML files the readers read):
no checkpoint, no data.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from expoctl.config_reader import Problems, Section
from expoctl.controllers.registry import CONTROLLERS
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.features.registry import FRONTENDS
from expoctl.labels.samples import SampleConfig
from expoctl.labels.targets import LabelConfig
from expoctl.numerics import NumericsConfig
from expoctl.parallel import ParallelConfig
from expoctl.raw.ingest import IngestConfig
from expoctl.report.results import ReportConfig
from expoctl.selection.model_selection import SelectConfig
from expoctl.sim.collect import CollectConfig, CollectInputs, plan_sequences, reference_controller_config
from expoctl.world.cities import deep_merge, resolve_city_name
from stages.collect import REFERENCE_GATES
from expoctl.bench.rl.config import read_rl_config
from stages.keys import LAST_ITERATION
from stages.project import PROJECT_ROOT
from stages.train import configs as train_configs

#: The resolved config's top-level keys: conf/config.yaml's groups (its defaults list) and own keys, and what the
#: scale presets (conf/scale/*.yaml, package _global_) add. tests/stages/test_config_check.py checks it against conf/.
TOP_LEVEL_KEYS = ("sensor", "world", "rig", "controllers", "collect", "ingest", "features", "labels", "samples",
                  "model", "train", "select_model", "evaluate", "report", "parallel", "numerics", "rl", "seed",
                  "paths", "scale_name") + tuple(
    f"iteration{n}" for n in range(2, LAST_ITERATION + 1))
#: `paths` (conf/config.yaml); an `iteration<N>.paths` block overrides some of them, all but the final model
PATH_KEYS = ("raw_dir", "frames", "images_dir", "features", "matches", "labels", "samples", "model", "final_model",
             "reports_dir")
ITERATION_PATH_KEYS = tuple(k for k in PATH_KEYS if k != "final_model")


def check_resolved(cfg: dict[str, Any], project_root: Path = PROJECT_ROOT) -> None:
    """Raise one ConfigError naming every problem of the composed config `cfg` (full dotted keys); None if valid.
    A relative `world.city_dir` is read under `project_root`."""
    problems = Problems()
    top = Section(cfg, "", problems)
    collect = problems.collect(CollectInputs.from_resolved, cfg)  # reader that stops at its end: collected
    # every group through its reader, one signature (d, key, problems): all their problems in this one pass
    for group, key in ((IngestConfig, "ingest"), (LabelConfig, "labels"), (SampleConfig, "samples"),
                       (ReportConfig, "report")):
        group.from_dict(top.value(key, None), key, problems)
    problems.collect(train_configs, cfg)  # model, train, seed: as the train stage builds them
    ParallelConfig.from_dict(top.value("parallel", None), "parallel", problems)  # where jobs run (as collect reads it)
    NumericsConfig.from_dict(top.value("numerics", None), "numerics", problems)  # as every stage's boot reads it
    select = SelectConfig.from_dict(top.value("select_model", None), "select_model", problems)
    read_rl_config(top.value("rl", None), problems)  # the train_rl stage's group, checked even when it is off
    # evaluate, features (every front end's typed config), world, rig, sensor, every controllers.<name> section
    evaluation = EvaluationInputs.from_resolved(cfg, problems)
    _check_plugins(problems)
    _check_cities(evaluation, select, project_root, problems)
    if collect is not None:
        problems.collect(plan_sequences, collect, project_root)  # each split with sequences has a valid city
    paths = top.section("paths", required=True)
    for name in PATH_KEYS:
        paths.text(name)
    paths.done()
    for n in range(2, LAST_ITERATION + 1):
        _check_iteration(cfg, n, top, collect, project_root, problems)
    _check_fixed_paths(cfg, problems)
    top.done(TOP_LEVEL_KEYS)
    # groups read by several stages (world, rig, sensor, seed) are reported once
    problems.items = list(dict.fromkeys(problems.items))
    problems.raise_if_any()


def _check_plugins(problems: Problems) -> None:
    """Every installed plugin that failed to load, named with its package: a user who installed one expects it in
    the run, so its absence stops compose rather than leaving it out unnoticed."""
    for registry in (CONTROLLERS, FRONTENDS):
        for name, (package, problem) in registry.broken().items():
            problems.add(f"{registry.config_key}.{name}", f"{registry.kind} plugin {name!r} (package {package}) is "
                                                          f"broken: {problem}")


def _check_collect(cfg: dict, ccfg: CollectConfig, key: str, problems: Problems) -> None:
    """The reference controller of a merged collect block is one the registry builds from its section alone."""
    controllers = Section(cfg.get("controllers"), "controllers", problems)
    reference_controller_config(controllers, ccfg.reference_controller, f"{key}.reference_controller")


def _check_cities(evaluation: EvaluationInputs, select: SelectConfig, project_root: Path, problems: Problems) -> None:
    """Every `world.cities` entry loads (unknown names list every name a user may give), and each city a stage asks
    for by split is configured."""
    world = evaluation.world.under(project_root)
    for split, spec in world.cities.items():
        problems.collect(resolve_city_name, spec, world.city_dir, f"world.cities.{split}")
    for split in evaluation.evaluate.splits:
        if split not in world.cities:
            problems.add(f"world.cities.{split}", f"missing: evaluate.splits.{split} needs a city")
    wanted = [("select_model.city", select.city)] if select.enabled else []
    wanted += [("select_model.probe.city", select.probe.city)] if select.probe.enabled else []
    for key, city in wanted:
        if city not in world.cities:
            problems.add(key, f"{city!r} is not a world.cities entry ({sorted(world.cities)})")


def _check_iteration(cfg: dict, n: int, top: Section, collect: CollectInputs | None, project_root: Path,
                     problems: Problems) -> None:
    """`iteration<N>`: enabled, reference_gate, its paths, and its `collect` block merged over `collect` (as
    stages/collect.py later_iteration_config merges it) is a valid collect config."""
    block = top.section(f"iteration{n}", required=True)
    enabled = block.boolean("enabled")
    block.choice("reference_gate", REFERENCE_GATES)
    paths = block.section("paths", required=True)
    for name in ITERATION_PATH_KEYS:
        paths.text(name, None)
    paths.done()
    override = block.value("collect", None)
    block.done()
    if override is not None and not isinstance(override, dict):
        block.problem("collect", f"must be a mapping, got {override!r}")
        return
    base = cfg.get("collect")
    if not isinstance(base, dict):
        return  # reported as `collect`
    key = f"iteration{n}.collect"
    own = Problems()
    ccfg = CollectConfig.from_dict(deep_merge(base, override or {}), key, own)
    _check_collect(cfg, ccfg, key, own)
    # a problem of the base `collect` is already reported under `collect`: only the block's own ones count
    inherited = set(problems.items)
    problems.items += [(k, p) for k, p in own.items if ("collect" + k[len(key):], p) not in inherited]
    if collect is not None and enabled and not own.items:
        problems.collect(plan_sequences, dataclasses.replace(collect, collect=ccfg), project_root)


def _check_fixed_paths(cfg: dict, problems: Problems) -> None:
    """`paths.*` and `iteration<N>.paths.*` name the DVC outputs that dvc.yaml declares, so they cannot move: a stage
    told to write elsewhere writes outside DVC's view, and collect, which replaces its output directory whole, would
    delete whatever is there (a recording under `paths.raw_dir=data/rig`, say). Real recordings have their own home."""
    import yaml

    defaults = yaml.safe_load((Path(__file__).resolve().parents[1] / "conf" / "config.yaml").read_text())
    blocks = [("paths", defaults.get("paths") or {})] + [
        (f"iteration{n}.paths", (defaults.get(f"iteration{n}") or {}).get("paths") or {})
        for n in range(2, LAST_ITERATION + 1)]
    for key, fixed in blocks:
        node: Any = cfg
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            continue  # reported by the readers above
        for name, value in node.items():
            if name in fixed and isinstance(value, str) and value != fixed[name]:  # a non-string: reported above
                problems.add(f"{key}.{name}", f"is {fixed[name]!r}, fixed by dvc.yaml (a stage output), got "
                             f"{value!r}; real recordings go in data/recordings with collect.source=recordings "
                             "(docs/raw_format.md)")
