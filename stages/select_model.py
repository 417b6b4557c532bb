"""select_model stage: every iteration's network drives the training city in closed loop and the best one becomes the
pipeline's final model, `paths.final_model` (+ its .onnx), which evaluate drives (expoctl.selection.model_selection).

Candidates: iteration 1's network and that of every enabled later iteration (a disabled iteration's model is a copy
of the previous one). First the saturation probe (`select_model.probe`, on by default) drops every candidate with a
saturated closed-loop fixed point (all stay if all fail). With `select_model.enabled: false` the final model is then
the last remaining candidate's (the paper's choice when every candidate passes); with `enabled: true` the remaining
ones drive the selection windows. reports/select_model.json records the candidates, the probe, the closed-loop
statistics and the choice.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import shutil
import sys
import time
from pathlib import Path

from expoctl.config_reader import Problems
from expoctl.errors import InputError
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.net.checkpoint import check_checkpoint
from expoctl.parallel import ParallelConfig
from expoctl.selection.saturation_probe import summary_line
from expoctl.selection.model_selection import Candidate, SelectConfig, probe_candidates, probe_filter, select_model
from stages.common import PROJECT_ROOT, stage_main
from stages.keys import LAST_ITERATION

log = logging.getLogger(__name__)

PROBE_RULE = ("the saturation probe drops candidates with a saturated closed-loop fixed point (some start ends with "
              "at least select_model.probe.max_saturated_fraction of the frame clipped, or "
              "max_dark_fraction of it black)")
RULE = ("most windows with VO tracking, then the highest mean over ORB and libviso2-style of the dynamic-section "
        "minimum NFM relative to the best candidate's, then the later iteration")


def candidates(cfg: dict, root: Path) -> list[Candidate]:
    out = [Candidate("iteration1", 1, root / cfg["paths"]["model"])]
    for n in range(2, LAST_ITERATION + 1):
        block = cfg[f"iteration{n}"]
        if block.get("enabled", True):
            out.append(Candidate(f"iteration{n}", n, root / block["paths"]["model"]))
    return out


def check_candidates(cands: list[Candidate]) -> None:
    """Every candidate's checkpoint and .onnx (both are copied to the final model), checked before any work: one
    InputError naming each bad file and what is wrong with it."""
    problems = []
    for c in cands:
        missing = [p for p in (c.path, c.path.with_suffix(".onnx")) if not p.is_file()]
        if missing:
            problems += [f"{p}: the {c.name} network is missing (run its train stage first)" for p in missing]
            continue
        try:
            check_checkpoint(c.path, onnx=True)
        except InputError as exc:
            problems.append(f"{exc} (the {c.name} network)")
    if problems:
        raise InputError("\n".join(problems))


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def run(cfg: dict, tracker, project_root: Path | None = None) -> None:
    from expoctl.io import atomic_path, write_json

    root = Path(project_root or PROJECT_ROOT)
    problems = Problems()  # every config problem at once, before any work
    scfg = SelectConfig.from_dict(cfg.get("select_model"), "select_model", problems)
    inputs = EvaluationInputs.from_resolved(cfg, problems)
    parallel = ParallelConfig.from_resolved(cfg, problems)  # where the probe and the runs go
    problems.raise_if_any()
    cands = candidates(cfg, root)
    check_candidates(cands)
    probe = None
    pool = cands
    if scfg.probe.enabled and len(cands) > 1:
        t0 = time.perf_counter()
        results = probe_candidates(inputs, cands, root, scfg.probe, parallel)
        pool = probe_filter(cands, results)
        failed = [c.name for c in cands if not results[c.name]["passes"]]
        probe = {"config": dataclasses.asdict(scfg.probe), "results": results, "failed": failed,
                 "kept": [c.name for c in pool],
                 "note": ("every candidate failed: all kept" if len(failed) == len(cands) else
                          "candidates that failed are not chosen" if failed else "every candidate passed"),
                 "seconds": round(time.perf_counter() - t0, 1)}
        for c in cands:
            log.info("probe %s", summary_line(c.name, results[c.name]))
    if scfg.enabled:
        result = select_model(inputs, scfg, pool, root, progress=sys.stderr.isatty(), parallel=parallel)
        chosen, scores, reference, seconds = result.chosen, result.scores, result.reference, result.seconds
        windows = [{"sequence": w.sequence, "label": w.label, "start": w.start, "stop": w.stop}
                   for w in result.windows]
        runs = [] if result.runs.empty else result.runs[["run_id", "candidate", "sequence", "vo_success",
                                                         "vo_failed_at", "vo_min_inliers"]].to_dict("records")
        rule = RULE if scores else "one candidate: nothing to choose between"
    else:
        chosen, scores, reference, seconds, windows, runs = pool[-1], [], None, 0.0, [], []
        rule = "select_model.enabled is false: the last remaining iteration's network (the paper's choice)"
    if probe is not None:
        rule = f"{PROBE_RULE}; then {rule}"
    note = failed_probe_note(chosen, cands, probe, scfg)
    if note is not None:
        log.warning("%s", note)
    final = root / cfg["paths"]["final_model"]
    for src, dst in ((chosen.path, final), (chosen.path.with_suffix(".onnx"), final.with_suffix(".onnx"))):
        with atomic_path(dst) as tmp:
            shutil.copyfile(src, tmp)
    report = {
        "chosen": chosen.name,
        "final_model": cfg["paths"]["final_model"],
        "rule": rule,
        "chosen_failed_probe": note is not None,
        "note": note,
        "city": scfg.city,
        "reference": scfg.reference if scores else None,
        "candidates": [{"name": c.name, "iteration": c.iteration, "path": str(c.path.relative_to(root))
                        if c.path.is_relative_to(root) else str(c.path), "sha256": _sha256(c.path)} for c in cands],
        "probe": probe,
        "scores": scores,
        "reference_statistics": reference,
        "windows": windows,
        "runs": runs,
        "seconds": seconds,
    }
    out = root / cfg["paths"]["reports_dir"] / "select_model.json"
    write_json(report, out)
    tracker.log_params({"chosen": chosen.name})
    metrics = {"seconds": seconds, "chosen_iteration": chosen.iteration}
    if probe is not None:
        metrics["probe_seconds"] = probe["seconds"]
        metrics["chosen_failed_probe"] = int(note is not None)
    for name, r in ((probe or {}).get("results") or {}).items():
        metrics[f"{name}.probe_worst_saturated_frac"] = r["worst_saturated_frac"]
        metrics[f"{name}.probe_worst_dark_frac"] = r["worst_dark_frac"]
        metrics[f"{name}.probe_passes"] = int(r["passes"])
    for s in scores + ([reference] if reference else []):
        metrics[f"{s['name']}.vo_ok"] = s["vo_ok"]
        metrics[f"{s['name']}.median_saturated_frac"] = s["median_saturated_frac"]
        for fe, v in s["dynamic_min_nfm"].items():
            if v is not None:
                metrics[f"{s['name']}.dynamic_min_nfm.{fe}"] = v
        for k in ("score", "median_offset_ev"):
            if s.get(k) is not None:
                metrics[f"{s['name']}.{k}"] = s[k]
    tracker.log_metrics(metrics)
    tracker.log_artifact(out)
    for s in scores:
        d = s["dynamic_min_nfm"]
        log.info("%-11s VO %d/%d, dynamic min NFM %s, score %.3f, %s EV from %s, clipped %.0f %%",
                 s["name"], s["vo_ok"], s["vo_runs"], ", ".join(f"{fe} {_fmt(v)}" for fe, v in d.items()), s["score"],
                 _fmt(s.get("median_offset_ev"), "+.2f"), scfg.reference, 100 * (s["median_saturated_frac"] or 0))
    log.info("final model: %s → %s (%s)", chosen.name, final, rule)


def failed_probe_note(chosen: Candidate, cands: list[Candidate], probe: dict | None, scfg: SelectConfig) -> str | None:
    """None when the chosen network passed the saturation probe (or no probe ran); otherwise the sentence that says
    it failed, how, and why it was still picked (logged as a WARNING and recorded in reports/select_model.json)."""
    if probe is None or probe["results"][chosen.name]["passes"]:
        return None
    r, pc = probe["results"][chosen.name], scfg.probe
    how = []
    if "white" in r["fails_on"]:
        how.append(f"worst start ends {100 * r['worst_saturated_frac']:.0f} % clipped white, at least "
                   f"select_model.probe.max_saturated_fraction {pc.max_saturated_fraction:g}")
    if "black" in r["fails_on"]:
        how.append(f"darkest start ends {100 * r['worst_dark_frac']:.0f} % black, at least "
                   f"select_model.probe.max_dark_fraction {pc.max_dark_fraction:g}")
    failed = probe["failed"]
    if len(failed) == len(cands):
        why = (f"every candidate failed the probe ({', '.join(failed)}), so it could exclude none and all were kept; "
               + ("the selection windows then chose this one" if scfg.enabled else
                  "select_model.enabled is false, so the last remaining iteration's network was kept"))
    else:
        why = f"the probe kept {', '.join(probe['kept'])} and this one was chosen among them"
    return (f"the final model {chosen.name} FAILED the saturation probe ({'; '.join(how)}) but was still chosen: "
            f"{why}. It may run the camera into saturation: check reports/select_model.json's probe results before "
            "trusting the evaluation")


def _fmt(v, spec: str = ".0f") -> str:
    return "—" if v is None else format(v, spec)


if __name__ == "__main__":
    stage_main("select_model", run)
