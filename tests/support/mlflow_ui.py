"""A real `mlflow server` on 127.0.0.1 and a headless Chromium that opens its UI as a new user's browser would.

Used by tests/stages/test_mlflow_ui_browser.py and benchmarks/mlflow_ui_check.py (which also saves the screenshots
in docs/). The browser is the system's Chromium (Debian's `chromium` package) driven through its own command line
(`--headless --dump-dom --screenshot`), so no browser automation package, and no browser download, is needed. Each
call starts a fresh profile: empty local storage, which is where the MLflow UI keeps a user's choices, i.e. what a
first visit sees. `--virtual-time-budget` lets the page run (timers, the UI's API calls) for that much page time
and stops the clock while network requests are pending, so the DOM is dumped once the runs table has loaded.
"""

from __future__ import annotations

import html
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

STARTUP_TIMEOUT_S = 240.0  # a loaded shared 2-core machine took 87 s to start it
VIRTUAL_TIME_MS = 10_000   # page time for the UI to fetch and render; its fetches pause the clock
# a cap in real time too: a request that never ends would stop the page's clock for good (a loaded 2-core machine
# took 22 s for a page, and once more than 120 s); then the DOM is dumped as it stands and the caller's checks decide
PAGE_TIMEOUT_S = 90.0
BROWSER_TIMEOUT_S = PAGE_TIMEOUT_S + 60.0
WINDOW = (1600, 900)

# a per-(controller, city) child run's metrics, as stages/evaluate.py child_metrics names them
_KINDS, _FRONT_ENDS, _STATS = ("static", "dynamic"), ("orb", "viso", "orb_sumlog", "viso_sumlog"), ("median_nfm",
                                                                                                    "min_nfm")


def chromium() -> str | None:
    """The system Chromium's executable, or None."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def store_uri(workdir: Path) -> str:
    """The SQLite store `mlflow_server(workdir)` serves: fill it directly first (no HTTP round trips), then serve."""
    return f"sqlite:///{workdir / 'server.db'}"


@contextmanager
def mlflow_server(workdir: Path, startup_timeout_s: float = STARTUP_TIMEOUT_S) -> Iterator[str]:
    """`mlflow server` on a free 127.0.0.1 port with `store_uri(workdir)` and artifacts in `workdir`; yields its
    base URL. Always killed (its own process group, the workers included), also when the caller fails."""
    port = _free_port()
    log_path = workdir / "server.log"
    cmd = [sys.executable, "-m", "mlflow", "server", "--host", "127.0.0.1", "--port", str(port), "--workers", "1",
           "--backend-store-uri", store_uri(workdir),
           "--artifacts-destination", str(workdir / "artifacts")]
    with open(log_path, "wb") as log:
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, cwd=workdir)
        base = f"http://127.0.0.1:{port}"
        try:
            while True:
                if proc.poll() is not None:
                    raise RuntimeError(f"mlflow server exited ({proc.returncode}):\n{log_path.read_text()[-3000:]}")
                try:
                    with urllib.request.urlopen(f"{base}/health", timeout=2) as r:
                        if r.status == 200:
                            break
                except OSError:
                    pass
                if time.monotonic() - t0 > startup_timeout_s:
                    raise RuntimeError(f"mlflow server not healthy after {startup_timeout_s:.0f} s:\n"
                                       f"{log_path.read_text()[-3000:]}")
                time.sleep(0.5)
            print(f"mlflow server healthy after {time.monotonic() - t0:.1f} s")
            yield base
        finally:
            try:
                os.killpg(proc.pid, signal.SIGTERM)
                proc.wait(timeout=15)
            except ProcessLookupError:
                pass
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=15)


@dataclass(frozen=True)
class EvaluateRuns:
    experiment_id: str
    parent: str
    controllers: tuple[str, ...]


def log_evaluate_runs(controllers=("agae", "oracle", "learned"), splits=("validation", "test"),
                      other_stages=("compose", "ingest", "train"), experiment: str | None = None) -> EvaluateRuns:
    """Fill the current tracking store the way the pipeline does: `init_tracking`'s experiment, a few stage runs, an
    evaluate run with one child run per (controller, split) tagged and named as stages/evaluate.py names them (made-up
    but distinct metrics: the controller's index sets its level), and the view `log_child_runs` sets at its end.
    `experiment`: a plain experiment of that name instead, no view set, as stores were before the view existed."""
    import mlflow

    from stages.tracking import init_tracking, set_compare_view

    exp = init_tracking() if experiment is None else mlflow.create_experiment(experiment)
    for stage in other_stages:
        with mlflow.start_run(experiment_id=exp, run_name=stage, tags={"stage": stage}):
            mlflow.log_metric("stage_seconds", 1.0)
    with mlflow.start_run(experiment_id=exp, run_name="evaluate", tags={"stage": "evaluate"}) as parent:
        mlflow.log_metric("n_runs", len(controllers) * len(splits))
        for split in splits:
            for i, ctrl in enumerate(controllers):
                tags = {"stage": "evaluate", "controller": ctrl, "city": split, "route_split": split,
                        "parent_stage_run": parent.info.run_id}
                with mlflow.start_run(run_name=f"{ctrl} @ {split}", experiment_id=exp, nested=True, tags=tags):
                    mlflow.log_metrics({f"{k}.{fe}.{s}": 40.0 + 10 * i + j
                                        for j, (k, fe, s) in enumerate((k, fe, s) for k in _KINDS
                                                                       for fe in _FRONT_ENDS for s in _STATS)})
                    mlflow.log_metrics({"tracking_success_rate": 1.0, "controller_ms_median_mean": 0.1 * (i + 1)})
        if experiment is None:
            set_compare_view(exp, evaluate_run=parent.info.run_id)
    return EvaluateRuns(exp, parent.info.run_id, tuple(controllers))


@dataclass(frozen=True)
class Page:
    dom: str
    text: str   # the visible text, tags stripped, whitespace collapsed


def open_page(url: str, screenshot: Path | None = None, virtual_time_ms: int = VIRTUAL_TIME_MS) -> Page:
    """Load `url` in a fresh headless Chromium; return its DOM and text, and save a screenshot if asked."""
    exe = chromium()
    if exe is None:
        raise RuntimeError("no Chromium found: apt-get install chromium")
    for attempt in (1, 2):  # a second try in a fresh profile: a page once hung past its caps on a machine at load 100
        with tempfile.TemporaryDirectory() as profile:
            cmd = [exe, "--headless", "--no-sandbox",  # root in CI: Chromium's sandbox refuses to run as root
                   "--disable-gpu", "--no-first-run", f"--user-data-dir={profile}", "--hide-scrollbars",
                   f"--window-size={WINDOW[0]},{WINDOW[1]}", f"--virtual-time-budget={virtual_time_ms}",
                   f"--timeout={int(PAGE_TIMEOUT_S * 1000)}", "--dump-dom"]
            if screenshot is not None:
                screenshot.parent.mkdir(parents=True, exist_ok=True)
                cmd.append(f"--screenshot={screenshot}")
            t0 = time.monotonic()
            # its own process group, so that a timeout ends the renderer and GPU processes too, not only the browser
            proc = subprocess.Popen([*cmd, url], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                    cwd=profile,  # --screenshot without a path writes into the working directory
                                    start_new_session=True)
            try:
                out, err = proc.communicate(timeout=BROWSER_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.communicate()
                print(f"chromium: {url} timed out after {BROWSER_TIMEOUT_S:.0f} s (try {attempt})")
                continue
            finally:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)  # helpers left behind would keep writing the profile
                except ProcessLookupError:
                    pass
            print(f"chromium: {url} in {time.monotonic() - t0:.1f} s")
            break
    else:
        raise RuntimeError(f"chromium did not load {url} in two tries of {BROWSER_TIMEOUT_S:.0f} s")
    if proc.returncode != 0 or not out.strip():
        raise RuntimeError(f"chromium failed ({proc.returncode}):\n{err[-3000:]}")
    text = html.unescape(re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", re.sub(
        r"<(script|style)\b.*?</\1>", " ", out, flags=re.S))))
    return Page(out, text)
