"""What a new user sees in the MLflow UI, before and after expoctl sets its experiment up (issue 45, item 2).

Serves one store with two experiments filled the way the pipeline fills them (tests/support/mlflow_ui.py): one made
as stores were before `expoctl.tracking_ui` (a plain experiment) and the pipeline's `expoctl` (init_tracking and the
evaluate stage's view), opens each in a fresh headless Chromium (empty local storage: a first visit) and saves:

- docs/mlflow_before_landing.png: the plain experiment's landing page, MLflow 3.17's GenAI overview;
- docs/mlflow_before_runs.png: its runs tab: the controllers folded under the evaluate run, no metric columns;
- docs/mlflow_runs_view.png: the `expoctl` experiment's view: the controllers flat, leaderboard metrics as columns.

It asserts what each page says (the same checks as tests/stages/test_mlflow_ui_browser.py, plus the before pages),
so a new MLflow whose UI behaves otherwise stops it. Needs Debian's chromium. ~1-2 min on 2 cores.

    .venv/bin/python benchmarks/mlflow_ui_check.py            # the three PNGs in docs/
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.support.mlflow_ui import log_evaluate_runs, mlflow_server, open_page, store_uri  # noqa: E402

GENAI_ONLY = ("Tool calls", "Judges", "Detect Issues")


def shrink(png: Path) -> None:
    """A 256-colour palette: the UI's flat colours survive it, and the file is a fraction of the size."""
    from PIL import Image

    with Image.open(png) as im:
        im.convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(png, optimize=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs", help="where the screenshots go (default docs/)")
    args = ap.parse_args()
    import mlflow

    from expoctl import tracking_ui
    from stages.tracking import LEADERBOARD_METRICS

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        os.environ["MLFLOW_TRACKING_URI"] = store_uri(work)
        before = log_evaluate_runs(experiment="expoctl (no view: as before)")
        after = log_evaluate_runs()
        mlflow.set_tracking_uri(None)
        with mlflow_server(work) as base:
            shots = {}
            landing = open_page(f"{base}/#/experiments/{before.experiment_id}",
                                shots.setdefault("landing", args.out / "mlflow_before_landing.png"))
            assert any(w in landing.text for w in GENAI_ONLY), "the landing page is no longer the GenAI overview"
            runs_tab = open_page(f"{base}/#/experiments/{before.experiment_id}/runs?workflowType=machine_learning",
                                 shots.setdefault("runs", args.out / "mlflow_before_runs.png"))
            assert "evaluate" in runs_tab.text and "agae @" not in runs_tab.text, "child runs are no longer folded"
            assert not any(m in runs_tab.text for m in LEADERBOARD_METRICS), "metric columns shown by default"
            view = open_page(f"{base}/{tracking_ui.runs_view_path(after.experiment_id)}",
                             shots.setdefault("view", args.out / "mlflow_runs_view.png"))
            assert not any(w in view.text for w in GENAI_ONLY), view.text[:2000]
            assert all(f"{c} @ {s}" in view.text for c in after.controllers for s in ("validation", "test"))
            assert all(m in view.text for m in LEADERBOARD_METRICS[:4]), view.text[:3000]
    for name, png in shots.items():
        shrink(png)
        print(f"{name}: {png.relative_to(ROOT) if png.is_relative_to(ROOT) else png} ({png.stat().st_size // 1024} KB)")


if __name__ == "__main__":
    main()
