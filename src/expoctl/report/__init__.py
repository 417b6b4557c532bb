"""The evaluation report: reports/results.md with the paper-shaped tables (`results`) and its figures (`figures`)."""

from expoctl.report.figures import controller_timeline
from expoctl.report.results import ReportConfig, build_report

__all__ = ["ReportConfig", "build_report", "controller_timeline"]
