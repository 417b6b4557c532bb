"""The default pipeline of several commits, one after the other on this machine, as a new user runs it: a fresh
clone, `/usr/bin/time -v ./run.sh pipeline` (venv and install included, then `dvc repro` at the default scale).

For each commit it records the wall and CPU time and peak RSS from GNU time, each stage's seconds (the MLflow run
durations in the clone's mlflow.db), evaluate's seconds summed per controller (reports/eval/runs.parquet), how long
collect took to reach numba's cached renderer (its cold build) and the clone's reports/metrics.json. It merges them
into --out under "<commit>@<start time>", so an old and a new commit measured in one session land in one file and a
commit re-measured on another day or host is a new record, not an overwrite. The clones stay under --workdir (with
--workdir/shared pointing at ../shared, as the project expects) for inspection.

    .venv/bin/python benchmarks/pipeline_side_by_side.py f21af75 HEAD

--record CLONE records a clone whose `./run.sh pipeline` finished without this script (a session ended while the
driver waited on it): the same fields, from the clone's files, with `meta.recorded_after: true`.

Nothing else should run meanwhile: the pipeline uses both cores.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import re
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_meta import run_metadata  # noqa: E402

TIME_FIELDS = {"User time (seconds)": "user_s", "System time (seconds)": "sys_s",
               "Maximum resident set size (kbytes)": "max_rss_kb",
               "Elapsed (wall clock) time (h:mm:ss or m:ss)": "wall"}


def parse_time_v(text: str) -> dict:
    """GNU time -v's fields this benchmark reports; wall in seconds."""
    out = {}
    for line in text.splitlines():
        key, _, value = line.strip().partition(": ")
        if key in TIME_FIELDS:
            out[TIME_FIELDS[key]] = value.strip()
    parts = [float(p) for p in out.pop("wall").split(":")]
    wall = 0.0
    for p in parts:
        wall = wall * 60 + p
    return {"wall_s": wall, "cpu_s": float(out["user_s"]) + float(out["sys_s"]),
            "max_rss_mb": int(out["max_rss_kb"]) / 1024}


def stage_seconds(db: Path) -> dict[str, float]:
    """Each finished top-level MLflow run's duration by run name (the stage), read from the SQLite store."""
    con = sqlite3.connect(db)
    try:
        rows = con.execute("SELECT name, start_time, end_time FROM runs WHERE status = 'FINISHED' "
                           "AND end_time IS NOT NULL ORDER BY start_time").fetchall()
    finally:
        con.close()
    return {name: round((end - start) / 1000, 1) for name, start, end in rows}


def run_commit(commit: str, workdir: Path) -> dict:
    sha = subprocess.run(["git", "rev-parse", commit], cwd=ROOT, check=True, capture_output=True,
                         text=True).stdout.strip()
    clone = workdir / sha[:9]
    if clone.exists():
        raise SystemExit(f"pipeline_side_by_side: {clone} exists; remove it or choose another --workdir")
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    subprocess.run(["git", "checkout", "-q", sha], cwd=clone, check=True)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MLFLOW_", "VIRTUAL_ENV", "EXPOCTL_"))}
    # the caller's venv must not leak in: the clone installs its own, as a new user's does
    env["PATH"] = ":".join(p for p in env.get("PATH", "").split(":") if "/.venv/" not in p)
    log = clone / "pipeline.log"
    started = dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        proc = subprocess.run(["/usr/bin/time", "-v", "-o", str(clone / "time_v.txt"), "./run.sh", "pipeline"],
                              cwd=clone, env=env, stdout=fh, stderr=subprocess.STDOUT)
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"pipeline_side_by_side: {commit} ({sha[:9]}) failed with exit {proc.returncode}; see {log}")
    return {**clone_record(clone, sha, started), "elapsed_s": round(elapsed, 1)}


def evaluate_seconds_by_controller(runs_parquet: Path) -> dict[str, float]:
    """Closed-loop seconds of evaluate's runs summed per controller, plus their total: where the stage's time went
    (the stage's own wall time also holds start-up, fan-out waits and the report of its runs)."""
    import pandas as pd

    runs = pd.read_parquet(runs_parquet, columns=["controller", "seconds"])
    sums = runs.groupby("controller")["seconds"].sum()
    out = {str(c): round(float(v), 1) for c, v in sums.items()}
    out["all runs"] = round(float(runs["seconds"].sum()), 1)
    return out


def renderer_cold_build_s(clone: Path) -> float | None:
    """Seconds from collect's start (MLflow) to the write of numba's cache index of shade.render_kernel in the clone:
    the renderer's cold build, plus collect's few seconds of start-up before its first render. None when the clone
    has no such index (its renderer was built elsewhere)."""
    index = sorted((clone / "src" / "expoctl" / "world" / "__pycache__").glob("shade.render_kernel-*.nbi"))
    if not index:
        return None
    collect_ms = first_run_start_ms(clone / "mlflow.db", name="collect")
    if collect_ms is None:
        return None
    return round(index[0].stat().st_mtime - collect_ms / 1000, 1)


def first_run_start_ms(db: Path, name: str | None = None) -> int | None:
    """The earliest MLflow run start (ms since the epoch) in the SQLite store, of the runs called `name` if given."""
    con = sqlite3.connect(db)
    try:
        if name is None:
            return con.execute("SELECT MIN(start_time) FROM runs").fetchone()[0]
        return con.execute("SELECT MIN(start_time) FROM runs WHERE name = ?", (name,)).fetchone()[0]
    finally:
        con.close()


def clone_record(clone: Path, sha: str, started: str) -> dict:
    """What this benchmark records of a clone whose pipeline finished: GNU time's figures, stage seconds, evaluate's
    per-controller seconds, the renderer's cold build and the metrics."""
    return {"commit": sha, "started_utc": started, **parse_time_v((clone / "time_v.txt").read_text()),
            "stage_seconds": stage_seconds(clone / "mlflow.db"),
            "evaluate_run_seconds": evaluate_seconds_by_controller(clone / "reports" / "eval" / "runs.parquet"),
            "renderer_cold_build_s": renderer_cold_build_s(clone),
            "metrics": json.loads((clone / "reports" / "metrics.json").read_text())}


def record_finished_clone(clone: Path) -> dict:
    """clone_record of a clone left by an earlier, interrupted driver; its start is the first MLflow run's."""
    for needed in ("time_v.txt", "mlflow.db", "reports/metrics.json", "reports/eval/runs.parquet"):
        if not (clone / needed).is_file():
            raise SystemExit(f"pipeline_side_by_side: {clone / needed} is missing: that pipeline did not finish")
    sha = subprocess.run(["git", "rev-parse", "HEAD"], cwd=clone, check=True, capture_output=True,
                         text=True).stdout.strip()
    first = first_run_start_ms(clone / "mlflow.db")
    started = dt.datetime.fromtimestamp(first / 1000, dt.timezone.utc).isoformat(timespec="seconds")
    return clone_record(clone, sha, started)


def record_key(result: dict) -> str:
    return f"{result['commit']}@{result['started_utc']}"


def table(results: dict) -> str:
    commits = list(results)
    stages: list[str] = []
    for r in results.values():
        stages += [s for s in r["stage_seconds"] if s not in stages]
    head = "| | " + " | ".join(f"{results[c]['commit'][:9]} {results[c]['started_utc'][:10]}" for c in commits) + " |"
    rows = [head, "|---|" + "---:|" * len(commits)]
    rows.append("| whole run, install included (s) | " + " | ".join(f"{results[c]['wall_s']:.0f}" for c in commits) + " |")
    rows.append("| CPU (s) | " + " | ".join(f"{results[c]['cpu_s']:.0f}" for c in commits) + " |")
    rows.append("| peak RSS (MB) | " + " | ".join(f"{results[c]['max_rss_mb']:.0f}" for c in commits) + " |")
    for s in stages:
        rows.append(f"| {s} (s) | " + " | ".join(str(results[c]["stage_seconds"].get(s, "–")) for c in commits) + " |")
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("commits", nargs="*", help="git refs of this repository, run in this order")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/pipeline_side_by_side"))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "pipeline_side_by_side.json")
    ap.add_argument("--record", type=Path, nargs="+", default=[], metavar="CLONE",
                    help="record clones whose pipeline already finished, instead of running commits")
    args = ap.parse_args()
    if bool(args.commits) == bool(args.record):
        ap.error("give commits to run, or --record CLONE ..., not both and not neither")
    doc = json.loads(args.out.read_text()) if args.out.exists() else {"runs": {}}

    def save(result: dict, meta: dict) -> None:
        result["meta"] = meta
        doc["runs"][record_key(result)] = result
        tmp = args.out.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(doc, indent=2) + "\n")
        tmp.replace(args.out)
        print(f"{result['commit'][:9]}: {result['wall_s']:.0f} s wall, {result['cpu_s']:.0f} s CPU", flush=True)

    for clone in args.record:
        save(record_finished_clone(clone), {**run_metadata(), "recorded_after": True})
    if args.commits:
        args.workdir.mkdir(parents=True, exist_ok=True)
        shared = args.workdir / "shared"
        if not shared.exists():
            shared.symlink_to((ROOT.parent / "shared").resolve())
    for commit in args.commits:
        result = run_commit(commit, args.workdir)
        save(result, run_metadata())
    print(table(doc["runs"]))


if __name__ == "__main__":
    main()
