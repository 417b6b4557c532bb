"""report stage: reports/metrics.json + reports/eval/ → reports/results.md, reports/figures/*.png (expoctl.report)."""

from __future__ import annotations

import logging
from pathlib import Path

from expoctl.report.results import ReportConfig, build_report
from stages.common import PROJECT_ROOT, stage_main

log = logging.getLogger(__name__)


def run(cfg: dict, tracker, project_root: Path | None = None) -> None:
    root = Path(project_root or PROJECT_ROOT)
    rcfg = ReportConfig.from_dict(cfg.get("report"))  # ConfigError before any work
    written = build_report(root / cfg["paths"]["reports_dir"], rcfg)
    tracker.log_metrics({"n_figures": len(written) - 1})
    for p in written.values():
        tracker.log_artifact(p, artifact_path="report")
    log.info("wrote %s", ", ".join(str(p.relative_to(root)) if p.is_relative_to(root) else str(p)
                                   for p in written.values()))


if __name__ == "__main__":
    stage_main("report", run)
