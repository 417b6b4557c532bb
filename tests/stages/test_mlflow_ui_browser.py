"""The MLflow UI, opened in a headless Chromium as a new user would, shows the controllers side by side.

A real `mlflow server` on 127.0.0.1 serves a store filled the way the pipeline fills it (tests/support/mlflow_ui.py).
MLflow 3.17 opens an experiment on its GenAI overview whatever the experiment says (the choice is the browser's:
docs/pipeline.md#the-mlflow-ui), so the check is that (1) that first page links to the runs view, and (2) the link
opens the runs table with every (controller, split) run listed flat, the leaderboard metrics as columns, best first.
Needs the system Chromium (Debian: chromium); without it the test skips, unless EXPOCTL_REQUIRE_BROWSER_TESTS=1
(CI) makes that a failure.
"""

from __future__ import annotations

import os
import re

import mlflow
import pytest

from expoctl import tracking_ui
from tests.support.mlflow_ui import chromium, log_evaluate_runs, mlflow_server, open_page, store_uri

pytestmark = pytest.mark.skipif(chromium() is None and os.environ.get("EXPOCTL_REQUIRE_BROWSER_TESTS") != "1",
                                reason="no Chromium (apt-get install chromium)")

GENAI_ONLY = ("Tool calls", "Judges", "Detect Issues")  # the GenAI overview's tabs and sidebar entries


def test_the_ui_opens_on_the_controllers_with_leaderboard_columns(tmp_path, monkeypatch):
    from stages.tracking import LEADERBOARD_METRICS

    monkeypatch.setenv("MLFLOW_TRACKING_URI", store_uri(tmp_path))
    try:
        runs = log_evaluate_runs()
    finally:
        mlflow.set_tracking_uri(None)
    with mlflow_server(tmp_path) as base:
        view = tracking_ui.runs_view_path(runs.experiment_id)

        first = open_page(f"{base}/#/experiments/{runs.experiment_id}")
        # the landing page is MLflow's GenAI overview; its description (shown above every tab) links to the view
        assert any(w in first.text for w in GENAI_ONLY), first.text[:2000]
        assert "Compare controllers:" in first.text
        assert f'href="{view.replace("&", "&amp;")}"' in first.dom

        page = open_page(f"{base}/{view}")
    assert not [w for w in GENAI_ONLY if w in page.text], page.text[:2000]
    names = [f"{c} @ {s}" for s in ("validation", "test") for c in runs.controllers]
    assert all(n in page.text for n in names), page.text[:3000]
    assert f"{len(names)} matching runs" in page.text  # the child runs alone, flat: no stage runs, no parent
    # the grid renders only the columns in sight: the first four leaderboard metrics fit a 1600-pixel window
    assert all(m in page.text for m in LEADERBOARD_METRICS[:4]), page.text[:3000]
    assert "Sort: dynamic.orb.min_nfm" in page.text
    # best first: the controllers' metrics rise with their index (log_evaluate_runs)
    order = [m.group(1) for m in re.finditer(r"(\w+) @ (?:validation|test)", page.text)]
    ranked = sorted(runs.controllers, key=runs.controllers.index, reverse=True)
    assert [c for i, c in enumerate(order) if c not in order[:i]] == ranked, order
