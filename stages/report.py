"""report stage: reports/metrics.json + reports/eval/ → reports/results.md, reports/figures/*.png (expoctl.report),
reports/headline.json, the pipeline's one DVC metric (expoctl.report.headline), and reports/numerics.json: the numeric
mode, library versions and CPU of the run (expoctl.numerics; docs/reproducibility.md)."""

from __future__ import annotations

import logging
from pathlib import Path

from expoctl.io import write_json
from expoctl.net.checkpoint import check_checkpoint
from expoctl.report.headline import headline_metrics
from expoctl.report.results import ReportConfig, build_report, load_eval
from stages.common import PROJECT_ROOT, stage_main
from stages.numerics import stage_record

log = logging.getLogger(__name__)


def run(cfg: dict, tracker, project_root: Path | None = None) -> None:
    root = Path(project_root or PROJECT_ROOT)
    rcfg = ReportConfig.from_dict(cfg.get("report"))  # ConfigError before any work
    reports_dir = root / cfg["paths"]["reports_dir"]
    ckpt = check_checkpoint(root / cfg["paths"]["final_model"])  # the network evaluate drove, checked first
    metrics, _, runs = load_eval(reports_dir)
    headline = headline_metrics(metrics, runs, ckpt.get("metrics", {}).get("val_loss"))
    written = build_report(reports_dir, rcfg)
    write_json(headline, reports_dir / "headline.json")
    written["headline"] = reports_dir / "headline.json"
    # which mode, libraries and CPU: the one file of the run that names its host (the fixture manifest's exception)
    write_json(stage_record(cfg), reports_dir / "numerics.json")
    written["numerics"] = reports_dir / "numerics.json"
    tracker.log_metrics({"n_figures": len(written) - 3})
    for p in written.values():
        tracker.log_artifact(p, artifact_path="report")
    log.info("wrote %s", ", ".join(str(p.relative_to(root)) if p.is_relative_to(root) else str(p)
                                   for p in written.values()))


if __name__ == "__main__":
    stage_main("report", run)
