"""Closed-loop model selection: which iteration's network the pipeline hands to evaluation.

Why it exists: the paper keeps the last iteration's network. Measured here, a later iteration's network can settle at
a saturated closed-loop fixed point that its open-loop validation loss does not show (docs/runs/old_camera_results.md: seed 2's
iteration 2 scored the same validation loss as the sound networks, then ran +5.6 EV above AG+AE with 89 % of the
pixels clipped and lost VO on 3 of 4 windows). So every candidate network drives the simulated camera in closed
loop, with the evaluate stage's protocol (warm-up, render size, sensor randomisation, both front ends, VO), over
windows of the train or validation city (the latter already gives training its validation split) at traversals no
other stage drives; the test city stays unseen until evaluation. Measured limit: over two traversals of either city
seed 2's iteration 2 did not diverge (its divergence needs conditions those traversals lacked), so this stage did not
catch it and is off by default (docs/runs/old_camera_results.md).

First, the saturation probe (`expoctl.selection.saturation_probe`, `select_model.probe`, on by default and cheap: about
a minute per candidate at 320×240): each candidate starts in closed loop from its AG+AE level and from +6 EV above it,
on the open road and in a tunnel of the training city's traversal 900. A candidate that ends some start with ≥ 97 % of
the frame clipped has a saturated fixed point and is dropped (`probe_filter`; if every candidate fails, all stay). Every
network that diverged in the evaluation failed it; the default seed's final network passes (docs/runs/old_camera_results.md). With
`enabled: false` the last remaining candidate is the final model (the paper's choice among those that pass).

With `enabled: true` the remaining candidates then drive the selection windows; the rule, lexicographic (`choose`):
1. most windows on which VO keeps tracking;
2. the highest score: over the raw front ends (ORB, libviso2-style), the mean of the candidate's dynamic-section
   minimum NFM (mean over sections, as metrics.json) divided by the best candidate's — the paper's headline metric,
   with the two front ends weighted equally whatever their scales;
3. on an exact tie, the later iteration (the paper's choice).

Config: `select_model` (conf/select_model/default.yaml) as a `SelectConfig`, and the evaluation's `EvaluationInputs`,
both built once by the stage before any work.
"""

from __future__ import annotations

import dataclasses
import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from expoctl.camera.ranges import exposure_value_ev
from expoctl.errors import ConfigError, InputError
from expoctl.config_reader import Problems, Section
from expoctl.evaluation.config import SplitPlan, read_split_plan
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.parallel import ParallelConfig
from expoctl.selection.saturation_probe import ProbeConfig

#: route_split label of the selection's windows (it also seeds their traversals and noise, apart from evaluate's)
SELECT_LABEL = "select"


def reference_names() -> tuple[str, ...]:
    """The controllers the selection may drive beside the candidates, for its report (never chosen): those that
    need no network and no scene."""
    from expoctl.controllers.registry import controller_names

    return controller_names(runs_without=("checkpoint", "scene"))

#: the one city no stage before evaluate may see (the validation city already gives train its validation split)
HELD_OUT_CITY = "test"


@dataclass(frozen=True)
class SelectConfig:
    enabled: bool = False  # as conf/select_model/default.yaml: the paper's last-iteration choice unless asked
    city: str = "train"
    plan: SplitPlan = SplitPlan(SELECT_LABEL, first_traversal=300, n_traversals=1)
    reference: str | None = "agae"
    probe: ProbeConfig = ProbeConfig()

    @classmethod
    def from_dict(cls, d, key: str = "select_model", problems: Problems | None = None) -> "SelectConfig":
        r = Section(d, key, problems, required=True)
        enabled = r.boolean("enabled", cls.enabled)
        city = r.text("city", cls.city)  # a world.cities entry
        if city == HELD_OUT_CITY:
            r.problem("city", f"{city!r} is the held-out city: selecting on it would let the choice see the city the "
                      "result is reported on (use train or validation)")
        reference = r.choice("reference", (None,) + reference_names(), cls.reference)
        plan = read_split_plan(SELECT_LABEL, r)
        if not r.has("first_traversal"):
            plan = dataclasses.replace(plan, first_traversal=cls.plan.first_traversal)
        probe = ProbeConfig.from_dict(r.value("probe", None), r.path("probe"), r.problems)
        if probe.city == HELD_OUT_CITY:
            r.problem("probe.city", f"{probe.city!r} is the held-out city (use train or validation)")
        r.done()
        return cls(enabled, city, plan, reference, probe)


@dataclass(frozen=True)
class Candidate:
    name: str  # e.g. "iteration2"
    iteration: int
    path: Path


@dataclass
class SelectionResult:
    chosen: Candidate
    scores: list[dict]  # one per candidate (see `score_candidates`), in candidate order
    reference: dict | None  # the same statistics for the reference controller
    frames: pd.DataFrame  # per frame per run (evaluate's columns + "candidate")
    runs: pd.DataFrame
    windows: list
    seconds: float


# ---------------------------------------------------------------------------------------------------------- scoring


def run_statistics(frames: pd.DataFrame, runs: pd.DataFrame, sections: pd.DataFrame, name: str,
                   reference: str | None = None) -> dict:
    """Closed-loop statistics of one candidate (or the reference) over its runs: VO windows tracked, per raw front
    end the mean dynamic-section minimum and static-section median NFM, the median clipped share, and — when
    `reference` names another candidate in `frames` — the median exposure-product offset from it, frame by frame."""
    from expoctl.evaluation.aggregate import section_variants

    FRONTENDS = [v for v in section_variants(sections) if not v.endswith("_sumlog")]
    r = runs[runs["candidate"] == name]
    f = frames[frames["candidate"] == name]
    s = sections[sections["run_id"].isin(set(r["run_id"]))]
    out: dict = {"name": name, "vo_ok": int(r["vo_success"].sum()), "vo_runs": int(len(r))}
    for kind, stat in (("dynamic", "min"), ("static", "median")):
        sk = s[s["section"] == kind]
        out[f"{kind}_{stat}_nfm"] = {fe: (float(sk[f"{stat}_nfm_{fe}"].mean()) if len(sk) else None)
                                     for fe in FRONTENDS}
    out["median_saturated_frac"] = float(f["saturated_frac"].median()) if len(f) else None
    if reference is not None:
        ref = frames[frames["candidate"] == reference]
        both = f.merge(ref, on=["sequence", "frame"], suffixes=("", "_ref"))
        if len(both):
            ev = exposure_value_ev(both["gain_db"], both["exposure_us"])
            ev_ref = exposure_value_ev(both["gain_db_ref"], both["exposure_us_ref"])
            out["median_offset_ev"] = float(np.median(ev - ev_ref))
    return out


def score_candidates(stats: Sequence[dict]) -> list[dict]:
    """Each candidate's statistics plus `score`: the mean over the raw front ends of its dynamic minimum NFM over the
    best candidate's (a front end no candidate has a value for, or whose best is 0, counts 0 for all)."""
    out = []
    best = {}
    FRONTENDS = list(stats[0]["dynamic_min_nfm"]) if stats else []
    for fe in FRONTENDS:
        vals = [s["dynamic_min_nfm"][fe] for s in stats if s["dynamic_min_nfm"][fe] is not None]
        best[fe] = max(vals) if vals else 0.0
    for s in stats:
        ratios = []
        for fe in FRONTENDS:
            v = s["dynamic_min_nfm"][fe]
            ratios.append(0.0 if v is None or best[fe] <= 0 else v / best[fe])
        out.append({**s, "score": float(np.mean(ratios))})
    return out


def choose(candidates: Sequence[Candidate], scored: Sequence[dict]) -> Candidate:
    """The rule of the module docstring: most VO windows tracked, then highest score, then the later iteration."""
    if not candidates or len(candidates) != len(scored):
        raise ValueError("choose needs one score per candidate")
    ranked = sorted(zip(candidates, scored), key=lambda cs: (cs[1]["vo_ok"], cs[1]["score"], cs[0].iteration))
    return ranked[-1][0]


# ---------------------------------------------------------------------------------------------------------- probe


def probe_candidates(inputs: EvaluationInputs, candidates: Sequence[Candidate], project_root: str | os.PathLike,
                     pcfg: ProbeConfig, parallel: ParallelConfig | None = None) -> dict[str, dict]:
    """The saturation probe's result for each candidate (`SaturationProbe.run`), each network built as evaluate
    builds it (controllers.learned's keys with the candidate's checkpoint). The candidates fan out as evaluate's runs
    do (`parallel`, its n_jobs); a worker builds the probe's scene and AG+AE reference once."""
    from expoctl.parallel import run_ordered
    from expoctl.selection.saturation_probe import ProbeJob, make_probe, probe_job

    for c in candidates:
        if not Path(c.path).is_file():
            raise InputError(f"{c.path}: the {c.name} network is missing (run its train stage first)")
    learned = inputs.controller_config("learned")
    agae = inputs.controller_config("agae")
    root = str(Path(project_root).resolve())
    if not candidates:
        return {}
    if pcfg.city not in inputs.world.cities:  # before any worker starts (make_probe says it the same way)
        make_probe(pcfg, inputs.world, inputs.rig, inputs.sensor, agae, root)
    jobs = [ProbeJob(pcfg, inputs.world, inputs.rig, inputs.sensor, agae, root, c.name,
                     replace(learned, checkpoint=str(Path(c.path).resolve()))) for c in candidates]
    return {job.name: result for job, result in run_ordered(probe_job, jobs, None, parallel)}


def probe_filter(candidates: Sequence[Candidate], results: dict[str, dict]) -> list[Candidate]:
    """The candidates whose probe passed, in order; all of them when none passed (nothing better to choose)."""
    passing = [c for c in candidates if results[c.name]["passes"]]
    return passing or list(candidates)


# ---------------------------------------------------------------------------------------------------------- driving


def select_model(inputs: EvaluationInputs, scfg: SelectConfig, candidates: Sequence[Candidate],
                 project_root: str | os.PathLike = ".", progress: bool = False,
                 parallel: ParallelConfig | None = None) -> SelectionResult:
    """Drive every candidate (and the reference) over the selection windows (`run_jobs`, where `parallel` says);
    score; choose (no files written).

    One candidate alone is returned without driving anything (nothing to choose between)."""
    from expoctl.evaluation.runner import RunJob, city_windows, run_jobs, tune_sumlog_params
    from expoctl.evaluation.aggregate import add_section_ids, section_stats

    ecfg, rig = inputs.evaluate, inputs.rig
    if not candidates:
        raise InputError("model selection: no candidate network")
    names = [c.name for c in candidates]
    if len(set(names)) != len(names):
        raise ValueError(f"candidate names repeat: {names}")
    for c in candidates:
        if not Path(c.path).is_file():
            raise InputError(f"{c.path}: the {c.name} network is missing (run its train stage first)")
    t0 = time.perf_counter()
    if len(candidates) == 1:
        return SelectionResult(candidates[0], [], None, pd.DataFrame(), pd.DataFrame(), [], 0.0)
    if scfg.reference is not None and scfg.reference in names:
        raise ConfigError("select_model.reference", f"{scfg.reference!r} is also a candidate's name")
    evaluated = ecfg.splits.get(scfg.city)
    if evaluated is not None:  # the same city as an evaluation split: its traversals must stay the evaluation's own
        mine = set(range(scfg.plan.first_traversal, scfg.plan.first_traversal + scfg.plan.n_traversals))
        theirs = set(range(evaluated.first_traversal, evaluated.first_traversal + evaluated.n_traversals))
        if mine & theirs:
            raise ConfigError("select_model.first_traversal", f"traversals {sorted(mine & theirs)} of the "
                              f"{scfg.city} city are also evaluate.splits.{scfg.city}'s: choose disjoint ones")
    windows = city_windows(inputs, project_root, SELECT_LABEL, scfg.city, scfg.plan, "select_model", rig.fps,
                           ecfg.warmup_frames)
    sumlog = tune_sumlog_params(inputs, project_root, ecfg.sumlog_pairs)
    jobs = [RunJob(w, "learned", inputs, sumlog, str(c.path), label=c.name) for c in candidates for w in windows]
    if scfg.reference is not None:
        jobs += [RunJob(w, scfg.reference, inputs, sumlog, label=scfg.reference) for w in windows]
    rows, summaries = [], []
    for job, (r, s, _thumbs) in run_jobs(jobs, progress, parallel):
        rows.extend({**row, "candidate": job.label} for row in r)  # run_id is already job.run_id (named by label)
        summaries.append({**s, "candidate": job.label})
    frames = add_section_ids(pd.DataFrame(rows))
    runs = pd.DataFrame(summaries).sort_values("run_id").reset_index(drop=True)
    sections = section_stats(frames, ecfg.min_section_frames)
    ref = scfg.reference
    scored = score_candidates([run_statistics(frames, runs, sections, n, ref) for n in names])
    ref_stats = None if ref is None else run_statistics(frames, runs, sections, ref)
    chosen = choose(candidates, scored)
    return SelectionResult(chosen, scored, ref_stats, frames, runs, windows, time.perf_counter() - t0)
