"""`expoctl bench` on the fixture project: a controller written outside the repository (an import path to a module
in the working directory) is scored beside the baselines; the built-ins score exactly what evaluate records for them;
bad controllers, models and output folders stop it with a message and nothing written."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from eval_fixtures import make_fixture_project  # noqa: E402

from expoctl.cli import main  # noqa: E402

HOLD = '''
from expoctl.controllers.base import Controller, Settings


class Hold(Controller):
    """Holds 1 ms at 6 dB whatever it sees."""
    name = "hold"
    label = "Hold 1 ms"

    def reset(self, initial):
        pass

    def update(self, image, applied):
        return Settings(6.0, 1000.0)
'''


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("benchproj")
    cfg = make_fixture_project(root, controllers=["agae", "fixed"])
    (root / "configs").mkdir()
    (root / "configs/resolved.yaml").write_text(yaml.safe_dump(cfg))
    (root / "user_ctl.py").write_text(HOLD)
    return root, cfg


@pytest.fixture(scope="module")
def benched(project, tmp_path_factory):
    """One benchmark run: the user's controller beside AG+AE and Fixed, two worker processes (each re-imports the
    user's module), logged to a fresh MLflow store."""
    import os

    root, _ = project
    store = tmp_path_factory.mktemp("mlflow") / "bench.db"
    cwd = os.getcwd()
    os.chdir(root)
    try:
        rc = main(["bench", "--controller", "user_ctl:Hold", "--baselines", "agae,fixed", "--n-jobs", "2", "--bound",
                   "--mlflow-uri", f"sqlite:///{store}", "--out", "out"])
    finally:
        os.chdir(cwd)
    yield rc, json.loads((root / "out/leaderboard.json").read_text()), store
    # `main` ran in this process: the user's class stays registered as "hold" (as it would in a user's script);
    # other test modules expect only the installed controllers
    from expoctl.controllers.registry import CONTROLLERS

    CONTROLLERS.unregister("hold")
    sys.modules.pop("user_ctl", None)


def test_user_controller_is_scored_beside_the_baselines(benched, project):
    rc, doc, _ = benched
    root, _ = project
    assert rc == 0
    assert set(doc["controllers"]) == {"agae", "fixed", "hold"}
    assert doc["controllers"]["hold"]["import_path"] == "user_ctl:Hold"
    assert doc["candidates"] == ["hold"]
    rows = {(r["split"], r["controller"]): r for r in doc["leaderboard"]}
    assert set(rows) == {(s, c) for s in ("validation", "test")
                         for c in ("agae", "fixed", "hold", "offline_optimum")}
    assert rows["test", "hold"]["label"] == "Hold 1 ms"
    text = (root / "out/leaderboard.txt").read_text()
    assert "Hold 1 ms" in text and max(len(line) for line in text.splitlines()) <= 120


def test_builtins_score_what_evaluate_records(benched, project):
    """The same config through the evaluate stage's code: AG+AE's and Fixed's metrics are equal to the last digit."""
    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.evaluation.runner import evaluate

    _, doc, _ = benched
    root, cfg = project
    result = evaluate(EvaluationInputs.from_resolved(cfg), root)
    for split in ("validation", "test"):
        for name in ("agae", "fixed"):
            assert doc["metrics"][split][name] == json.loads(json.dumps(result.metrics[split][name]))
    assert doc["benchmark"]["sumlog"].startswith("tuned on data/frames.parquet")


def test_mlflow_has_one_top_level_run_per_controller(benched):
    import mlflow

    _, doc, store = benched
    client = mlflow.MlflowClient(f"sqlite:///{store}")
    exp = client.get_experiment_by_name("expoctl-bench")
    runs = client.search_runs([exp.experiment_id])
    assert sorted(r.data.tags["controller"] for r in runs) == ["agae", "fixed", "hold", "offline_optimum"]
    assert all("mlflow.parentRunId" not in r.data.tags for r in runs)
    hold = next(r for r in runs if r.data.tags["controller"] == "hold")
    row = next(r for r in doc["leaderboard"] if r["controller"] == "hold" and r["split"] == "test")
    assert hold.info.run_name == "Hold 1 ms"
    assert hold.data.metrics["test.orb.dynamic_min"] == row["nfm"]["orb"]["dynamic_min"]
    assert hold.data.params["import_path"] == "user_ctl:Hold"


@pytest.mark.parametrize("ref, expected", [
    ("no_such_ctl", "unknown controller 'no_such_ctl'"),
    ("user_ctl:Nope", "module 'user_ctl' has no attribute 'Nope'"),
    ("broken_ctl:X", "importing 'broken_ctl' failed: ZeroDivisionError"),
    ("user_ctl:Settings", "class Settings lacks the method(s) reset, update"),
])
def test_bad_controller_stops_before_any_work(project, tmp_path, capsys, monkeypatch, ref, expected):
    root, _ = project
    (tmp_path / "broken_ctl.py").write_text("X = 1 / 0\n")
    (tmp_path / "user_ctl.py").write_text(HOLD)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path))
    rc = main(["bench", "--project", str(root), "--controller", ref, "--baselines", "agae", "--no-mlflow",
               "--out", "out"])
    err = capsys.readouterr().err
    assert rc == 2 and expected in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_every_problem_named_at_once(project, tmp_path, capsys, monkeypatch):
    root, _ = project
    monkeypatch.chdir(tmp_path)
    rc = main(["bench", "--project", str(root), "--controller", "nope1", "--controller", "nope2",
               "--baselines", "agae,nope3", "--no-mlflow", "--out", "out"])
    err = capsys.readouterr().err
    assert rc == 2 and all(n in err for n in ("nope1", "nope2", "nope3"))
    assert not (tmp_path / "out").exists()


def test_out_folder_with_other_files_is_refused(project, tmp_path, capsys, monkeypatch):
    root, _ = project
    (tmp_path / "out").mkdir()
    (tmp_path / "out/thesis.tex").write_text("mine")
    monkeypatch.chdir(tmp_path)
    rc = main(["bench", "--project", str(root), "--baselines", "agae", "--no-mlflow", "--out", "out"])
    assert rc == 2 and "thesis.tex" in capsys.readouterr().err
    assert (tmp_path / "out/thesis.tex").read_text() == "mine"


def test_missing_model_and_bad_numbers(project, tmp_path, capsys, monkeypatch):
    root, _ = project
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "--project", str(root), "--model", "nowhere.pt", "--no-mlflow"]) == 2
    assert "nowhere.pt: no such trained model" in capsys.readouterr().err
    assert main(["bench", "--project", str(root), "--traversals", "0", "--no-mlflow"]) == 2
    assert "--traversals" in capsys.readouterr().err


def test_mlflow_view_opens_on_the_leaderboard(benched):
    """The experiment's saved view lists this invocation's runs with the leaderboard's columns (expoctl.tracking_ui)."""
    import mlflow

    _, doc, store = benched
    client = mlflow.MlflowClient(f"sqlite:///{store}")
    exp = client.get_experiment_by_name("expoctl-bench")
    view = json.loads(exp.tags["mlflow.sharedViewState.expoctl-bench-leaderboard"])
    state = json.loads(view["state"])
    bench_id = client.search_runs([exp.experiment_id])[0].data.tags["bench_id"]
    assert state["searchFilter"] == f"tags.bench_id = '{bench_id}'"
    assert exp.tags["mlflow.experimentKind"] == "custom_model_development"
    assert "test.orb.dynamic_min" in json.dumps(state)


def test_offline_optimum_heads_each_split(benched):
    """--bound: the offline optimum over the oracle's grid (6 candidates at fixture scale) is each split's first row,
    labelled with its grid, and its numbers are the bound's aggregate."""
    _, doc, _ = benched
    bound = doc["offline_bound"]
    assert bound["grid"]["label"] == "6-candidate ladder, 3 EV" or bound["grid"]["label"].startswith("6-candidate")
    for split in ("validation", "test"):
        rows = [r for r in doc["leaderboard"] if r["split"] == split]
        assert rows[0]["controller"] == "offline_optimum" and rows[0]["reference"]
        assert bound["grid"]["label"] in rows[0]["label"]
        assert rows[0]["nfm"]["orb"]["dynamic_min"] == bound["metrics"][split]["dynamic"]["orb"]["min_nfm"]
