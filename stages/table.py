"""The stage table: every DVC stage of the pipeline, once, with what it reads and writes.

dvc.yaml is generated from this table (`python -m stages.dvc_yaml --write`; tests/stages/test_table.py fails when
the committed file differs), and stages/keys.py derives from it the config keys each stage reads, logs to MLflow
and hashes into its `config_hash` tag. So a stage's DVC `params`, its data `deps` and `outs`, and what its run logs
cannot drift apart. Source-code deps are not listed here: the generator follows each stage module's imports.

Paths are templates over the stage's iteration: `{frames}` is `paths.frames` of conf/config.yaml in iteration 1 and
`iteration<N>.paths.frames` over it in iteration N; `{prev_frames}` is the previous iteration's; `{model_onnx}` is
`{model}` with the `.onnx` suffix. Config keys are templates too, over `{block}` (`iteration<N>`) and
`{prev_model_key}` (the key naming the previous iteration's model). The generator reads the path values; a stage at
run time needs only the keys, so this module imports nothing but the standard library (every stage imports it, and
every stage's DVC deps list it: keep it free of anything a stage does not need).

Adding a stage: write `stages/<name>.py` (stages/common.py `stage_main`), add its `Stage` to STAGES, run
`python -m stages.dvc_yaml --write`, and regenerate docs/pipeline.md's DAG (`dvc dag --md`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

#: Data-collection iterations 2 … LAST_ITERATION run as the DVC `foreach` stages `<name>_iter@<N>` (conf/config.yaml
#: `iteration<N>` blocks). The final model, which evaluate drives, is the one select_model chooses among them.
LAST_ITERATION = 3


@dataclass(frozen=True)
class Each:
    """`templates` once per iteration k of a range, with k's values: iterations `first` … N-1 of a later iteration N's
    stage (`upto="earlier"`), or `first` … LAST_ITERATION (`upto="last"`)."""

    templates: tuple[str, ...]
    first: int = 1
    upto: str = "earlier"

    def iterations(self, n: int) -> range:
        return range(self.first, (n if self.upto == "earlier" else LAST_ITERATION + 1))


@dataclass(frozen=True)
class Dep:
    """A data dependency (a path template) and, for dvc.yaml's reader, why the stage reads it."""

    path: str
    why: str = ""
    first_only: bool = False  # iteration 1 reads it, a later iteration of the stage does not


@dataclass(frozen=True)
class Out:
    """An output path template. Every output is `persist: true` (DVC does not delete it before the stage runs; the
    stage writes it atomically, so a failed run leaves the last good one). `cache: false` for small reports that are
    committed to git; `metric` for the one DVC metrics file."""

    path: str
    cache: bool = True
    metric: bool = False


@dataclass(frozen=True)
class Stage:
    """One DVC stage: `python -m stages.<name>`."""

    name: str
    #: the keys of configs/resolved.yaml it reads (templates over `{block}`), declared as its DVC params
    keys: tuple[str | Each, ...] = ()
    deps: tuple[str | Dep | Each, ...] = ()
    outs: tuple[Out, ...] = ()
    #: runs again in iterations 2 … LAST_ITERATION as `<name>_iter@<N>`, with these additions
    iterated: bool = False
    later_keys: tuple[str | Each, ...] = ()
    later_deps: tuple[str | Dep | Each, ...] = ()
    later_outs: tuple[Out, ...] = ()
    #: keys of configs/resolved.yaml it reads that are NOT DVC params: they choose only where and how fast its jobs
    #: run, never a byte of its outputs (tests/evaluation/test_ray_backend.py), so changing them re-runs nothing
    #: (tests/pipeline/test_dvc_pipeline.py). Its MLflow run logs them, its `config_hash` leaves them out.
    runtime_keys: tuple[str, ...] = ()
    #: params files it tracks whole (compose: all of params.yaml, so a stray key reaches it and is refused)
    whole_params: tuple[str, ...] = ()
    always_changed: bool = False
    comment: str = ""          # written above the stage in dvc.yaml
    later_comment: str = ""    # written above its `foreach` stage


#: What every later iteration's stage reads beyond its base stage: its own block's `enabled` and `paths`, and every
#: earlier iteration's paths (its raw directories are ingested again, the previous model is collect's reference, the
#: previous tables are reused).
LATER_KEYS: tuple[str | Each, ...] = ("{block}.enabled", "{block}.paths", Each(("{block}.paths",), first=2))
#: The raw data of every earlier iteration, which a later iteration's ingest reads again (and features looks up).
EARLIER_RAW = Each(("{raw_dir}",))
COPIED = "copied when the iteration is disabled (stages/common.py COPIED_WHEN_DISABLED)"
#: What a closed-loop rollout of the simulated rig reads.
ROLLOUT_KEYS = ("seed", "sensor", "world", "rig")
#: Every stage that computes runs under the numeric mode (stages/numerics.py): its bytes can depend on it.
NUMERIC_KEYS = ("numerics",)
#: `parallel` (backend, address: where the jobs run, never what they compute) is read by the stages that fan out, as a
#: runtime key: not a DVC param, so pointing a finished run at a Ray cluster re-runs nothing.
FAN_OUT = ("parallel",)

STAGES: tuple[Stage, ...] = (
    Stage("guard", outs=(Out("configs/guard.ok", cache=False), Out("configs/plugins.yaml", cache=False)),
          always_changed=True, comment=(
              "Runs first on every `dvc repro` and stops it when a DVC output directory holds files no stage wrote (a "
              "real recording put under data/raw, say), before DVC could delete them (stages/guard.py). Its stamp "
              "never changes; configs/plugins.yaml (the installed plugins' entry points) changes only when a plugin "
              "package is installed, removed or upgraded, and then compose re-runs and records them.")),
    Stage("compose", deps=("configs/guard.ok", Dep("configs/plugins.yaml", "the installed plugins, recorded as "
                                                                            "`plugins` in the resolved config")),
          whole_params=("params.yaml",),
          outs=(Out("configs/resolved.yaml", cache=False),), comment=(
              "conf/ + params.yaml `overrides` -> configs/resolved.yaml, every key checked (stages/config_check.py); "
              "it tracks all of params.yaml, so a key other than `overrides` (what `dvc exp run -S train.lr=...` "
              "adds) reaches it and is refused.")),
    Stage("collect",
          keys=(*ROLLOUT_KEYS, *NUMERIC_KEYS, "collect", "collect_controllers.{block}", "plugins.controllers",
                "paths.raw_dir"),
          runtime_keys=FAN_OUT,
          deps=(Dep("data/recordings", "collect.source: recordings copies these; never an output (stages/guard.py)",
                    first_only=True),),
          outs=(Out("{raw_dir}"),),
          iterated=True,
          later_keys=("{block}.collect", "{block}.reference_gate", "select_model.probe", "{prev_model_key}"),
          later_deps=(Dep("{prev_model}", "the previous iteration's network drives camera 1"), "{prev_model_onnx}"),
          later_outs=(Out("{reports_dir}/collect_reference.json", cache=False),),
          comment=("Camera 1 under collect.reference_controller; its `controllers.<name>` section is read through "
                   "collect_controllers, which compose derives (a DVC param key cannot depend on a setting)."),
          later_comment=(
              "The paper's second data-collection iteration, and a third beyond the paper (conf/config.yaml "
              "iteration<N>): the previous iteration's network is camera 1's reference if it passes the saturation "
              "probe, and the model is retrained on all data so far.")),
    Stage("ingest", keys=(*NUMERIC_KEYS, "ingest", "paths.raw_dir", "paths.frames", "paths.images_dir"),
          deps=("{raw_dir}",), outs=(Out("{frames}"), Out("{images_dir}")),
          iterated=True, later_deps=(Dep("{prev_frames}", COPIED), "{prev_images_dir}", EARLIER_RAW)),
    Stage("features", keys=(*NUMERIC_KEYS, "features", "plugins.frontends", "paths.frames", "paths.features",
                            "paths.matches"),
          runtime_keys=FAN_OUT,
          deps=("{frames}", "{raw_dir}"), outs=(Out("{features}"), Out("{matches}")),
          iterated=True, later_deps=(Dep("{prev_frames}", "the previous iteration's counts are reused"),
                                     "{prev_features}", "{prev_matches}", EARLIER_RAW)),
    Stage("labels", keys=(*NUMERIC_KEYS, "labels", "plugins.frontends", "paths.frames", "paths.features", "paths.matches",
                          "paths.labels", "paths.reports_dir"),
          deps=("{frames}", "{features}", "{matches}"),
          outs=(Out("{labels}"), Out("{reports_dir}/labels.md", cache=False),
                Out("{reports_dir}/labels.json", cache=False)),
          iterated=True, later_deps=(Dep("{prev_labels}", COPIED), "{prev_reports_dir}/labels.md",
                                     "{prev_reports_dir}/labels.json")),
    Stage("samples", keys=(*NUMERIC_KEYS, "samples", "paths.frames", "paths.labels", "paths.samples"),
          deps=("{frames}", "{labels}"), outs=(Out("{samples}"),),
          iterated=True, later_deps=(Dep("{prev_samples}", COPIED),)),
    Stage("train", keys=(*NUMERIC_KEYS, "seed", "model", "train", "sensor", "paths.samples", "paths.frames", "paths.images_dir",
                         "paths.model", "paths.reports_dir"),
          deps=("{samples}", "{frames}", "{images_dir}"),
          outs=(Out("{model}"), Out("{model_onnx}"), Out("{reports_dir}/train.json", cache=False)),
          iterated=True, later_deps=(Dep("{prev_model}", "copied when the iteration is disabled (stages/train.py)"),
                                     "{prev_model_onnx}", "{prev_reports_dir}/train.json")),
    Stage("select_model",
          keys=(*ROLLOUT_KEYS, *NUMERIC_KEYS, "controllers", "features", "evaluate", "select_model", "plugins",
                "paths.model", "paths.final_model", "paths.frames", "paths.reports_dir",
                Each(("{block}.enabled", "{block}.paths.model"), first=2, upto="last")),
          runtime_keys=FAN_OUT,
          deps=(Each(("{model}", "{model_onnx}"), upto="last"), "{frames}", "{raw_dir}"),
          outs=(Out("{final_model}"), Out("{final_model_onnx}"), Out("{reports_dir}/select_model.json", cache=False)),
          comment=(
              "Which iteration's network is the final model (beyond the paper, which keeps the last): the saturation "
              "probe drops candidates with a saturated closed-loop fixed point; with enabled: true the rest drive the "
              "training city in closed loop with evaluate's protocol. The choice is copied to the final model, which "
              "evaluate drives (conf/select_model/default.yaml).")),
    Stage("train_rl", keys=(*ROLLOUT_KEYS, *NUMERIC_KEYS, "rl", "evaluate", "features", "plugins.frontends"),
          outs=(Out("models/rl"),), comment=(
              "Optional, off by default (rl.enabled): a stable-baselines3 agent trained in expoctl/Exposure-v0 on the "
              "training city only, resumable from models/rl (raise rl.total_steps to continue); off, it writes only "
              "models/rl/DISABLED.json and evaluate skips the `rl` controller (docs/benchmark.md).")),
    Stage("evaluate",
          keys=(*ROLLOUT_KEYS, *NUMERIC_KEYS, "controllers", "features", "evaluate", "plugins", "paths.final_model",
                "paths.frames", "paths.reports_dir"),
          runtime_keys=FAN_OUT,
          deps=("{final_model}", "{final_model_onnx}", "{frames}", "{raw_dir}",
                Dep("models/rl", "the rl agent (train_rl), or its marker when that stage is off")),
          outs=(Out("{reports_dir}/eval"), Out("{reports_dir}/metrics.json", cache=False))),
    Stage("report", keys=(*NUMERIC_KEYS, "report", "paths.reports_dir", "paths.final_model"),
          deps=("{reports_dir}/metrics.json", "{reports_dir}/eval", "{reports_dir}/select_model.json",
                "{final_model}"),
          outs=(Out("{reports_dir}/results.md", cache=False), Out("{reports_dir}/figures", cache=False),
                # the one DVC metric: a dozen headline numbers (src/expoctl/report/headline.py); the full tables
                # are the outputs reports/metrics.json, reports/eval/ and each iteration's train.json
                # the numeric mode, libraries and CPU the report ran with (each stage's own: its MLflow run's tags)
                Out("{reports_dir}/numerics.json", cache=False),
                Out("{reports_dir}/headline.json", cache=False, metric=True))),
)

STAGE_BY_NAME: dict[str, Stage] = {s.name: s for s in STAGES}


def key_vars(n: int) -> dict[str, str]:
    """The values of the placeholders a config-key template may use, in iteration `n`."""
    out = {"block": f"iteration{n}"}
    if n >= 2:
        out["prev_model_key"] = "paths.model" if n == 2 else f"iteration{n - 1}.paths"
    return out


def expand(entries: tuple, n: int, values: Callable[[int], dict[str, str]]) -> list[tuple[Any, dict[str, str]]]:
    """(entry, the placeholder values it is rendered with) for each entry in iteration `n`; an `Each` gives one per
    iteration k of its range, with k's values (`values(k)`) and its templates as entries."""
    out = []
    for entry in entries:
        if isinstance(entry, Dep) and entry.first_only and n >= 2:
            continue
        if isinstance(entry, Each):
            out += [(t, values(k)) for k in entry.iterations(n) for t in entry.templates]
        else:
            out.append((entry, values(n)))
    return out


def config_keys(stage: Stage, n: int) -> list[str]:
    """The config keys `stage` reads in iteration `n`, in order, each once."""
    entries = stage.keys + ((LATER_KEYS + stage.later_keys) if n >= 2 else ())
    return list(dict.fromkeys(t.format(**v) for t, v in expand(entries, n, key_vars)))


def collect_controller_names(cfg: dict[str, Any], n: int) -> list[str]:
    """The controllers whose `controllers.<name>` section collect reads in iteration `n` of the composed, checked
    config `cfg` (stages/collect.py): iteration 1 builds `collect.reference_controller`. A later iteration builds
    `iteration<N>.collect.reference_controller` (merged over `collect`); when that is the network and the reference
    gate is `probe`, also AG+AE, which the saturation probe drives (expoctl.selection.saturation_probe.make_probe),
    and iteration 1's reference, the gate's fallback. A superset is safe (an extra re-run), a missing name is not."""
    base = cfg.get("collect") or {}
    first = base.get("reference_controller")
    if n == 1:
        return [first] if first is not None else []
    block = cfg.get(f"iteration{n}") or {}
    reference = {**base, **(block.get("collect") or {})}.get("reference_controller")
    names = [reference]
    if reference == "learned" and block.get("reference_gate", "probe") == "probe":
        names += ["agae", first]
    return [name for name in dict.fromkeys(names) if name is not None]


def derived_config(cfg: dict[str, Any]) -> dict[str, Any]:
    """What compose adds to the checked config before writing configs/resolved.yaml: parts of the config whose place
    depends on a setting, copied to a fixed key that a stage can declare as a DVC param.

    `plugins`: the installed plugins (`recorded_plugins`).
    `collect_controllers.iteration<N>`: {name: controllers.<name>} for each controller collect builds in iteration N.
    collect reads them from `controllers`; DVC tracks this copy, which compose writes from the same config, so it
    changes exactly when a section collect reads does (with `collect.reference_controller: shin`, `controllers.shin`).
    Not a setting: check_resolved refuses a top-level key it does not know, so an override cannot set it.
    """
    controllers = cfg.get("controllers") or {}
    return {"collect_controllers": {
        f"iteration{n}": {name: controllers.get(name) for name in collect_controller_names(cfg, n)}
        for n in range(1, LAST_ITERATION + 1)},
        "plugins": recorded_plugins()}


#: the entry point groups of expoctl's plugin registries (expoctl.controllers.registry, expoctl.features.registry)
PLUGIN_GROUPS = {"controllers": "expoctl.controllers", "frontends": "expoctl.frontends"}


def recorded_plugins() -> dict[str, dict[str, str]]:
    """`plugins` of the resolved config: {controllers: {name: "<package> <version>: <target>"}, frontends: {...}} of
    the installed plugin packages, read from their metadata without importing them. guard writes the same list to
    configs/plugins.yaml, on which compose depends; the stages that build controllers or front ends declare it, so
    installing, removing or upgrading a plugin re-runs them (collect: only for the controllers)."""
    from importlib import metadata

    out = {}
    for kind, group in PLUGIN_GROUPS.items():
        eps = sorted(metadata.entry_points(group=group), key=lambda ep: ep.name)
        out[kind] = {ep.name: (f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else "?") + f": {ep.value}"
                     for ep in eps}
    return out
