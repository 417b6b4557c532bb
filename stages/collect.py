"""collect stage: drive the simulated dual-camera rig → data/raw/<split>/<sequence>/ (see expoctl.sim.collect)."""

from __future__ import annotations

import logging
import sys
import time

from expoctl.sim.collect import CollectInputs, collect
from stages.common import PROJECT_ROOT, stage_main

log = logging.getLogger(__name__)


#: iteration<N>.reference_gate: probe = the previous iteration's network drives camera 1 only if it passes the
#: saturation probe (select_model.probe's test), otherwise iteration 1's reference does; none = always the network
#: (the paper). Why: a network that runs into saturation records white frames whose labels can only say "darker"
#: (docs/runs/calibrated_seeds/README.md: seed 4's iteration-2 camera 1 was a median 98.7 % clipped).
REFERENCE_GATES = ("probe", "none")
REFERENCE_REPORT = "collect_reference.json"


def later_iteration_config(cfg: dict) -> dict:
    """collect_iter<N>: `iteration<N>.collect` merged over `collect`; the previous iteration's network drives camera 1.

    Disabled (`iteration<N>.enabled: false`): every split records zero sequences, so the iteration adds no data.
    """
    from expoctl.config_reader import Problems, Section
    from expoctl.world.cities import deep_merge

    n, block = cfg["iteration"], cfg["iteration_block"]
    problems = Problems()
    r = Section(block, f"iteration{n}", problems)
    enabled = r.boolean("enabled")
    gate = r.choice("reference_gate", REFERENCE_GATES)
    problems.raise_if_any()
    collect_cfg = deep_merge(cfg["collect"], block.get("collect") or {})
    if not enabled:
        collect_cfg["splits"] = {k: None if v is None else {**v, "n_sequences": 0}  # None: records nothing already
                                 for k, v in collect_cfg["splits"].items()}
    controllers = dict(cfg.get("controllers") or {})
    if collect_cfg.get("reference_controller") == "learned":
        checkpoint = PROJECT_ROOT / cfg["paths_prev"]["model"]
        if enabled and not checkpoint.is_file():
            from expoctl.errors import ConfigError

            key = "paths.model" if n == 2 else f"iteration{n - 1}.paths.model"
            raise ConfigError(key, f"{checkpoint}: the iteration-{n - 1} model is missing (run its train stage)")
        controllers["learned"] = {**(controllers.get("learned") or {}), "checkpoint": str(checkpoint)}
        if enabled:  # the network drives camera 1 (or the reference gate's probe): checked before any work
            from expoctl.net.checkpoint import check_checkpoint

            check_checkpoint(checkpoint, onnx=controllers["learned"].get("backend", "torch") == "onnx")
    # the gate's fallback is iteration 1's reference, `collect.reference_controller` before the merge
    return {**cfg, "collect": collect_cfg, "controllers": controllers, "enabled": enabled, "reference_gate": gate,
            "reference_fallback": cfg["collect"].get("reference_controller")}


def gate_reference(cfg: dict) -> tuple[dict, dict]:
    """Apply `iteration<N>.reference_gate` to a later iteration's config: (the config camera 1 is driven with, the
    decision as recorded in reports/iter<N>/collect_reference.json)."""
    from expoctl.config_reader import Problems
    from expoctl.controllers.registry import make_controller
    from expoctl.errors import ConfigError
    from expoctl.selection.saturation_probe import ProbeConfig, make_probe

    n, gate, network = cfg["iteration"], cfg["reference_gate"], cfg["collect"].get("reference_controller")
    decision = {"iteration": n, "reference_gate": gate, "network": f"iteration{n - 1}", "probe": None,
                "reference_controller": network}
    if gate == "none" or network != "learned" or not cfg["enabled"]:
        return cfg, decision
    fallback = cfg["reference_fallback"]
    if fallback == "learned":
        raise ConfigError("collect.reference_controller", "is learned, so reference_gate: probe has nothing to fall "
                          f"back to (set iteration{n}.reference_gate: none or an AE as iteration 1's reference)")
    problems = Problems()  # a bad probe and a bad collect block are reported together, before the probe runs
    pcfg = problems.collect(ProbeConfig.from_dict, (cfg.get("select_model") or {}).get("probe"), "select_model.probe")
    inputs = problems.collect(CollectInputs.from_resolved, cfg)  # world, rig and sensor, checked
    problems.raise_if_any()
    probe = make_probe(pcfg, inputs.world, inputs.rig, inputs.sensor, (cfg["controllers"] or {}).get("agae") or {},
                       PROJECT_ROOT)
    result = probe.run(make_controller("learned", cfg["controllers"]["learned"]))
    decision["probe"] = result
    if result["passes"]:
        return cfg, decision
    decision["reference_controller"] = fallback
    return {**cfg, "collect": {**cfg["collect"], "reference_controller": fallback}}, decision


def from_recordings(cfg: dict, tracker) -> None:
    """collect.source: recordings: the real rig recordings of data/recordings (never a stage's output, so never
    deleted) are validated and copied into paths.raw_dir; nothing is simulated. A later iteration would need new
    recordings driven by the previous network on the real camera, so it adds no sequences (say so, loudly)."""
    from expoctl.io import atomic_dir, write_json
    from expoctl.raw.recordings import copy_recordings
    from stages.project import RECORDINGS_DIR

    out_dir = PROJECT_ROOT / cfg["paths"]["raw_dir"]
    n = cfg.get("iteration", 1)
    if n > 1:
        with atomic_dir(out_dir):
            pass  # an empty raw directory: this iteration adds no data
        write_json({"iteration": n, "reference_controller": None, "source": "recordings",
                    "note": "collect.source is recordings: no sequences were recorded for this iteration"},
                   PROJECT_ROOT / cfg["paths"]["reports_dir"] / REFERENCE_REPORT)
        log.warning("collect.source is recordings: iteration %d adds no sequences. Record them on the rig with the "
                    "iteration-%d network as camera 1's reference (expoctl record --reference learned, docs/camera.md)"
                    " or set iteration%d.enabled=false", n, n - 1, n)
        tracker.log_metrics({"n_sequences": 0})
        return
    t0 = time.perf_counter()
    summaries = copy_recordings(PROJECT_ROOT / RECORDINGS_DIR, out_dir, progress=log.info)
    tracker.log_params({"source": "recordings"})
    tracker.log_metrics({"n_sequences": len(summaries), "n_frame_pairs": sum(s["n_frames"] for s in summaries),
                         "n_dynamic_sections": sum(s["n_dynamic_sections"] for s in summaries),
                         "seconds": time.perf_counter() - t0})
    log.info("%d recorded sequences from %s → %s (nothing simulated)", len(summaries), RECORDINGS_DIR, out_dir)


def run(cfg: dict, tracker) -> None:
    if (cfg.get("collect") or {}).get("source") == "recordings":
        CollectInputs.from_resolved(cfg)  # the whole config checked, as for a simulated collect
        from_recordings(cfg, tracker)
        return
    decision = None
    if cfg.get("iteration", 1) > 1:
        cfg, decision = gate_reference(later_iteration_config(cfg))
        report = PROJECT_ROOT / cfg["paths"]["reports_dir"] / REFERENCE_REPORT
    inputs = CollectInputs.from_resolved(cfg)  # every config problem at once, before any work
    if decision is not None:
        from expoctl.io import write_json
        from expoctl.selection.saturation_probe import summary_line

        if decision["probe"] is not None:
            log.info("reference gate: %s", summary_line(decision["network"], decision["probe"]))
        log.info("iteration %d: camera 1 is driven by %s", decision["iteration"], decision["reference_controller"])
        tracker.log_params({"reference_controller": decision["reference_controller"]})
        if decision["probe"] is not None:
            tracker.log_metrics({"reference_probe_passes": int(decision["probe"]["passes"]),
                                 "reference_probe_worst_saturated_frac": decision["probe"]["worst_saturated_frac"],
                                 "reference_probe_worst_dark_frac": decision["probe"]["worst_dark_frac"]})
    out_dir = PROJECT_ROOT / cfg["paths"]["raw_dir"]
    t0 = time.perf_counter()
    # a bar on a terminal; under DVC (no tty) log lines: every 30 s each sequence in progress (frame pairs done /
    # total, elapsed, rate; expoctl.sim.collect.PROGRESS_EVERY_S), and one per finished sequence
    summaries = collect(inputs, out_dir, progress=True if sys.stderr.isatty() else log.info, project_root=PROJECT_ROOT)
    if decision is not None:
        write_json(decision, report)
    seconds = time.perf_counter() - t0
    n_frames = sum(s["n_frames"] for s in summaries)
    metrics = {
        "n_sequences": len(summaries),
        "n_frame_pairs": n_frames,
        "n_dynamic_sections": sum(s["n_dynamic_sections"] for s in summaries),
        "seconds": seconds,
        "frame_pairs_per_s": n_frames / max(seconds, 1e-9),
    }
    for split in ("train", "validation", "test"):
        metrics[f"n_sequences_{split}"] = sum(1 for s in summaries if s["split"] == split)
        metrics[f"n_frame_pairs_{split}"] = sum(s["n_frames"] for s in summaries if s["split"] == split)
    tracker.log_metrics(metrics)
    for s in summaries:
        log.info("%s: %d frames, %d dynamic sections, camera-1 exposure %.0f–%.0f µs, gain up to %.1f dB",
                 s["sequence"], s["n_frames"], s["n_dynamic_sections"], s["cam1_exposure_us_min"],
                 s["cam1_exposure_us_max"], s["cam1_gain_db_max"])
    log.info("%d sequences, %d frame pairs in %.1f s → %s", len(summaries), n_frames, seconds, out_dir)


if __name__ == "__main__":
    stage_main("collect", run)
