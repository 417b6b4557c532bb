"""Closed-loop evaluation: the `evaluate` config group (`config`), one run of one controller over one window (`run`),
the planning and fan-out of all runs and the stage's outputs (`runner`) and the aggregation into
reports/metrics.json (`aggregate`).
"""

from expoctl.evaluation.aggregate import add_section_ids, section_stats, validate_metrics
from expoctl.evaluation.config import EvaluateConfig, SplitPlan
from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.evaluation.runner import (RunJob, city_windows, evaluate, metrics_summary, run_jobs, tune_sumlog_params,
                                       write_outputs)

__all__ = ["EvaluateConfig", "EvaluationInputs", "RunJob", "SplitPlan", "add_section_ids", "city_windows",
           "evaluate", "metrics_summary", "run_jobs", "section_stats", "tune_sumlog_params",
           "validate_metrics", "write_outputs"]
