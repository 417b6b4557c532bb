"""The default pipeline of several commits, one after the other on this machine, as a new user runs it: a fresh
clone, `/usr/bin/time -v ./run.sh pipeline` (venv and install included, then `dvc repro` at the default scale).

For each commit it records the wall and CPU time and peak RSS from GNU time, each stage's seconds (the MLflow run
durations in the clone's mlflow.db) and the clone's reports/metrics.json, and merges them into --out keyed by commit,
so an old and a new commit measured in one session land in one file. The clones stay under --workdir (with
--workdir/shared pointing at ../shared, as the project expects) for inspection.

    .venv/bin/python benchmarks/pipeline_side_by_side.py f21af75 HEAD

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
    metrics = json.loads((clone / "reports" / "metrics.json").read_text())
    return {"commit": sha, "started_utc": started, "elapsed_s": round(elapsed, 1),
            **parse_time_v((clone / "time_v.txt").read_text()),
            "stage_seconds": stage_seconds(clone / "mlflow.db"), "metrics": metrics}


def table(results: dict) -> str:
    commits = list(results)
    stages: list[str] = []
    for r in results.values():
        stages += [s for s in r["stage_seconds"] if s not in stages]
    head = "| | " + " | ".join(c[:9] for c in commits) + " |"
    rows = [head, "|---|" + "---:|" * len(commits)]
    rows.append("| whole run, install included (s) | " + " | ".join(f"{results[c]['wall_s']:.0f}" for c in commits) + " |")
    rows.append("| CPU (s) | " + " | ".join(f"{results[c]['cpu_s']:.0f}" for c in commits) + " |")
    rows.append("| peak RSS (MB) | " + " | ".join(f"{results[c]['max_rss_mb']:.0f}" for c in commits) + " |")
    for s in stages:
        rows.append(f"| {s} (s) | " + " | ".join(str(results[c]["stage_seconds"].get(s, "–")) for c in commits) + " |")
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("commits", nargs="+", help="git refs of this repository, run in this order")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/pipeline_side_by_side"))
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "pipeline_side_by_side.json")
    args = ap.parse_args()
    args.workdir.mkdir(parents=True, exist_ok=True)
    shared = args.workdir / "shared"
    if not shared.exists():
        shared.symlink_to((ROOT.parent / "shared").resolve())
    doc = json.loads(args.out.read_text()) if args.out.exists() else {"runs": {}}
    for commit in args.commits:
        result = run_commit(commit, args.workdir)
        result["meta"] = run_metadata()
        doc["runs"][result["commit"]] = result
        tmp = args.out.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(doc, indent=2) + "\n")
        tmp.replace(args.out)
        print(f"{commit}: {result['wall_s']:.0f} s wall, {result['cpu_s']:.0f} s CPU", flush=True)
    print(table(doc["runs"]))


if __name__ == "__main__":
    main()
