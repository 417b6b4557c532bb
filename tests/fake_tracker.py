"""A stand-in for stages.tracking.Tracker: records what a stage logs, so stage tests run without an MLflow store."""

from __future__ import annotations


class FakeTracker:
    def __init__(self):
        self.params: dict = {}
        self.metrics: dict = {}
        self.artifacts: list[str] = []

    def log_params(self, params):
        self.params.update(params)

    def log_metrics(self, metrics, step=None):
        self.metrics.update(metrics)

    def log_artifact(self, path, artifact_path=None):
        self.artifacts.append(str(path))
