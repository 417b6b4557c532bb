"""Render once, share everywhere (expoctl.evaluation.runner.run_window): every run of a window driven in lockstep over
one cached scene, one renderer and one noise-remembering sensor gets exactly the rows, summary and thumbnails it gets
driven alone, with per-exposure renders (share_render false) and with one shared sharp render per frame (true)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from eval_fixtures import make_fixture_project

from expoctl.evaluation.inputs import EvaluationInputs
from expoctl.evaluation.runner import RunJob, plan_windows, run_window, tune_sumlog_params

#: columns that hold wall-clock time, the only ones allowed to differ between two runs of the same thing
CLOCK = ("controller_ms", "controller_ms_median", "seconds", "seconds_per_frame", "oracle_ms_median")
#: window-level sharing counters: a lone run's window renders less than seven runs' window
SHARED = ("window_renders", "window_sharp_renders", "window_noise_draws")


def _jobs(tmp_path, share_render: bool) -> list[RunJob]:
    root = tmp_path / f"proj-{share_render}"
    cfg = make_fixture_project(root)
    cfg["evaluate"]["share_render"] = share_render
    cfg["evaluate"]["splits"] = {"test": {**cfg["evaluate"]["splits"]["test"], "windows": [0, 1]}}
    inputs = EvaluationInputs.from_resolved(cfg)
    window = plan_windows(inputs, root)[0]
    sumlog = tune_sumlog_params(inputs, root, 2)
    model = str(root / "models/controller.pt")
    return [RunJob(window, c, inputs, sumlog, model) for c in ("oracle", "agae", "fixed", "learned", "shin")]


def _comparable(result):
    rows, summary, thumbs = result
    frame = pd.DataFrame(rows).drop(columns=[c for c in CLOCK if c in rows[0]])
    return frame, {k: v for k, v in summary.items() if k not in CLOCK + SHARED}, thumbs


@pytest.mark.parametrize("share_render", [False, True])
def test_lockstep_window_equals_every_run_driven_alone(tmp_path, share_render):
    jobs = _jobs(tmp_path, share_render)
    together = run_window(tuple(jobs))
    for job, shared in zip(jobs, together):
        alone = run_window((job,))[0]
        (f_shared, s_shared, t_shared), (f_alone, s_alone, t_alone) = _comparable(shared), _comparable(alone)
        pd.testing.assert_frame_equal(f_shared, f_alone, check_exact=True)
        pd.testing.assert_series_equal(pd.Series(s_shared), pd.Series(s_alone), check_exact=True)
        assert np.array_equal(t_shared["image"], t_alone["image"]) and np.array_equal(t_shared["frame"],
                                                                                      t_alone["frame"])
    # the window was rendered once for all five: with sharing, one sharp render per frame (2 warm-up frames, the
    # recorded ones, the oracle's look-ahead at the stop); one noise field per frame either way
    n = together[0][1]["n_frames"]
    assert together[0][1]["window_noise_draws"] == n + 3
    if share_render:
        assert together[0][1]["window_sharp_renders"] == n + 3
    else:  # each (frame, exposure) its own render: at least the oracle's four candidates per frame after the first
        assert together[0][1]["window_sharp_renders"] >= 4 * (n + 2)


def test_runs_of_one_window_share_a_worker_and_come_back_in_job_order(tmp_path):
    from expoctl.evaluation.runner import run_jobs

    jobs = _jobs(tmp_path, True)
    inputs, sumlog = jobs[0].inputs, jobs[0].sumlog
    windows = plan_windows(inputs, tmp_path / "proj-True")
    assert len(windows) == 2  # test: the entry and the exit window
    # controller-major, as evaluate plans them: windows interleave
    plan = [RunJob(w, c, inputs, sumlog, jobs[0].model_path) for c in ("agae", "fixed") for w in windows]
    got = list(run_jobs(plan, False))
    assert [job.run_id for job, _ in got] == [job.run_id for job in plan]
    for job, (rows, summary, _) in got:
        assert summary["run_id"] == job.run_id and {r["controller"] for r in rows} == {job.controller}


def test_run_window_refuses_jobs_of_two_windows(tmp_path):
    jobs = _jobs(tmp_path, False)
    other = plan_windows(jobs[0].inputs, tmp_path / "proj-False")
    second = RunJob(other[1], "agae", jobs[0].inputs, jobs[0].sumlog)
    with pytest.raises(ValueError, match="same window"):
        run_window((jobs[1], second))
