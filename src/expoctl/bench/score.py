"""Score controllers on the benchmark routes: evaluate's closed loop, windows and statistics, with a controller list
of the caller's (`expoctl bench`).

The benchmark is evaluate itself: the same windows (`evaluate.splits`, one traversal each unless `traversals`
asks for more), the same scene, sensor, noise seeds, warm-up, front ends and statistics, so a built-in controller
scores here exactly what the evaluate stage records for it at the same config (tested). What it adds: controllers
that are not in the config (an installed plugin, or an import path "module:Class"), always scored beside every
baseline, the learned network when a trained model exists, and the greedy oracle.

SumLog (the `<fe>_sumlog` columns of the JSON; the leaderboard's table shows the raw front ends only): tuned as
evaluate tunes it when the project's training frames exist (`paths.frames`), else the untuned transform
(`SumLogParams()`), and the JSON says which.
"""

from __future__ import annotations

import copy
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from expoctl.errors import ConfigError, InputError


@dataclass(frozen=True)
class BenchmarkPlan:
    """What one benchmark run scores, on which windows, with which inputs (everything checked, nothing run)."""

    inputs: Any                      # EvaluationInputs (evaluate's controller list = `controllers`)
    controllers: tuple[str, ...]     # registry names, in table order; candidates last
    candidates: tuple[str, ...]      # those the user asked for (beside the baselines)
    references: dict[str, str]       # {name: "module:Class"} for candidates given by import path
    model_path: str | None           # the learned network scored, or None (no trained model)
    windows: list = field(repr=False, default_factory=list)
    skipped: dict[str, str] = field(default_factory=dict)  # {controller: why it is not scored}
    parallel: Any = None             # ParallelConfig: where the runs go (None: this process)


def plan_benchmark(cfg: dict, project_root: str | os.PathLike, candidates: Sequence[str] = (),
                   traversals: int | None = None, model: str | os.PathLike | None = None,
                   n_jobs: int | None = None, baselines: Sequence[str] | None = None) -> BenchmarkPlan:
    """Check everything before any work: every candidate resolves (an unknown or broken one is a ConfigError naming
    it), the config reads, the windows exist. `cfg`: a resolved config (a project's configs/resolved.yaml or the
    packaged benchmark config); `traversals`: traversals per split (default: the config's); `model`: the learned
    network (default: the config's final model, when that file exists); `baselines`: the registered controllers
    scored beside the candidates (default: every one)."""
    from expoctl.controllers.registry import CONTROLLERS, controller_names, resolve_controller
    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.evaluation.runner import check_controllers, plan_windows

    root = Path(project_root)
    problems: list[tuple[str, str]] = []
    references: dict[str, str] = {}
    names: list[str] = []
    for i, ref in enumerate(candidates):
        try:
            name = resolve_controller(ref, f"--controller {ref}")
        except ConfigError as exc:
            problems += exc.problems
            continue
        if ":" in ref:
            references[name] = ref
        if name in names:
            problems.append((f"--controller {ref}", f"names controller {name!r} twice"))
        names.append(name)
    if baselines is not None:
        if not baselines:
            problems.append(("--baselines", "names no controller"))
        for b in baselines:
            if ":" in b:
                problems.append(("--baselines", f"{b!r}: baselines are registered names; give import paths with "
                                                "--controller"))
            else:
                problems += [("--baselines", p) for _k, p in CONTROLLERS.problems([b], "--baselines")]
    if problems:
        raise ConfigError.of(problems)
    if traversals is not None and (isinstance(traversals, bool) or int(traversals) != traversals or traversals < 1):
        raise ConfigError("--traversals", f"must be an integer >= 1, got {traversals!r}")

    cfg = copy.deepcopy(cfg)
    paths = cfg.setdefault("paths", {})
    model_path = Path(model) if model is not None else None
    if model_path is None:
        learned = (cfg.get("controllers") or {}).get("learned") or {}
        default = learned.get("checkpoint") or paths.get("final_model") or paths.get("model")
        model_path = (root / default) if default else None
    elif not model_path.is_file():
        raise InputError(f"{model_path}: no such trained model (--model)")
    skipped: dict[str, str] = {}
    builtins = [n for n in controller_names() if n not in names and (baselines is None or n in baselines)]
    if "learned" in builtins and (model_path is None or not model_path.is_file()):
        builtins.remove("learned")
        skipped["learned"] = (f"no trained model at {model_path}" if model_path else "no trained model configured")
        model_path = None
    if "learned" not in builtins + names:
        model_path = None
    # `rl` (opt-in, expoctl.bench.rl.controller): scored when its trained agent exists, as `learned` with its model
    from expoctl.bench.rl.controller import with_rl

    if "rl" not in names and (baselines is None or "rl" in baselines):
        cfg, why = with_rl({**cfg, "evaluate": {**(cfg.get("evaluate") or {}), "controllers": None}}, root)
        if why is None:
            builtins = [n for n in controller_names(opt_in=True) if n in builtins or n == "rl"]
        else:
            skipped["rl"] = why
    if "rl" in builtins + names:
        cfg, _ = with_rl(cfg, root, ["rl"])
    paths = cfg.setdefault("paths", {})  # with_rl returned a copy
    if model_path is not None:
        paths["model"] = str(model_path.resolve())
        cfg.setdefault("controllers", {}).setdefault("learned", {}).pop("checkpoint", None)
    ev = cfg.setdefault("evaluate", {})
    ev["controllers"] = builtins + names
    from expoctl.parallel import ParallelConfig

    parallel = ParallelConfig.from_resolved(cfg).with_jobs(n_jobs)  # the config's `parallel`, --n-jobs over it
    if traversals is not None:
        for plan in (ev.get("splits") or {}).values():
            if isinstance(plan, dict):
                plan["n_traversals"] = int(traversals)
    inputs = EvaluationInputs.from_resolved(cfg)
    check_controllers(inputs.evaluate.controllers, inputs, references)
    windows = plan_windows(inputs, root)
    ordered = tuple(n for n in controller_names(opt_in=True) if n in inputs.evaluate.controllers)
    ordered += tuple(n for n in inputs.evaluate.controllers if n not in ordered)
    return BenchmarkPlan(inputs, ordered, tuple(names), references,
                         None if model_path is None else str(model_path), windows, skipped, parallel)


def reference_names(names: Sequence[str]) -> tuple[str, ...]:
    """The controllers among `names` that see the simulator's scene (the greedy oracle): references, not causal."""
    from expoctl.controllers.registry import needs

    return tuple(n for n in names if "scene" in needs(n))


@dataclass
class BenchmarkOutcome:
    plan: BenchmarkPlan
    result: Any                      # EvaluationResult (metrics.json object, per-frame and per-run tables)
    sumlog_source: str
    seconds: float
    bound: dict | None = None        # `expoctl.evaluation.offline_bound.evaluate_bounds`'s object, when asked for


def run_benchmark(plan: BenchmarkPlan, project_root: str | os.PathLike = ".", progress: bool = False,
                  parallel=None, bound: bool = False) -> BenchmarkOutcome:
    """Drive every controller of `plan` over its windows (evaluate's `evaluate_windows`) and aggregate; with `bound`,
    also the offline optimum of every window over the grid of `evaluate.offline_bound` (default: the oracle's
    ladder; docs/evaluation.md, The offline bound). `parallel`: where the runs go (default: the plan's, the config's
    `parallel` block with --n-jobs over it)."""
    from expoctl.evaluation.runner import evaluate_windows, tune_sumlog_params
    from expoctl.features.sumlog import SumLogParams

    inputs = plan.inputs
    parallel = plan.parallel if parallel is None else parallel
    frames = Path(project_root) / inputs.frames_path if inputs.frames_path else None
    if frames is not None and frames.is_file():
        sumlog = tune_sumlog_params(inputs, project_root, inputs.evaluate.sumlog_pairs)
        source = f"tuned on {inputs.frames_path} (as evaluate)"
    else:
        sumlog = {name: SumLogParams() for name in inputs.evaluate.frontends}
        source = "untuned (no training frames to tune on)"
    t0 = time.perf_counter()
    result = evaluate_windows(inputs, plan.windows, sumlog, plan.controllers, plan.model_path, progress, parallel,
                              plan.references)
    bounds = None
    if bound:
        from expoctl.evaluation.offline_bound import evaluate_bounds

        bounds = evaluate_bounds(inputs, plan.windows, sumlog, parallel)
    return BenchmarkOutcome(plan, result, source, time.perf_counter() - t0, bounds)
