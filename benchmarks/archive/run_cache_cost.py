"""What `persist: true` on every output costs: DVC's run-cache is off for such stages.

In a throw-away copy of a commit (git archive), at fixture scale: `dvc repro train`, then `train.lr` changed and
back, timing the repro that returns to the first settings. With the run-cache (outputs not persistent, before the
safety change) DVC restores train's outputs from the cache; with persist it re-runs train. Prints a table and writes
JSON. Usage: python benchmarks/archive/run_cache_cost.py OLD_COMMIT NEW_COMMIT [--out benchmarks/archive/results/run_cache_cost.json]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks


def _copy(commit: str, dest: Path) -> dict:
    dest.mkdir(parents=True)
    archive = subprocess.run(["git", "archive", commit], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    env = dict(os.environ, MLFLOW_TRACKING_URI=f"sqlite:///{dest / 'mlflow.db'}", PYTHONPATH=str(dest),
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}",
               GIT_AUTHOR_NAME="b", GIT_AUTHOR_EMAIL="b@b", GIT_COMMITTER_NAME="b", GIT_COMMITTER_EMAIL="b@b")
    for cmd in (["git", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", "copy"]):
        subprocess.run(cmd, cwd=dest, env=env, check=True, capture_output=True)
    return env


def _repro(dest: Path, env: dict, overrides: list[str]) -> tuple[float, set[str], str]:
    (dest / "params.yaml").write_text(json.dumps({"overrides": overrides}))
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "dvc", "repro", "train"], cwd=dest, env=env, capture_output=True,
                       text=True)
    if p.returncode != 0:
        raise SystemExit(f"dvc repro failed in {dest}:\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}")
    out = p.stdout
    return time.perf_counter() - t0, set(re.findall(r"Running stage '([\w@-]+)'", out)), out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "archive" / "results" / "run_cache_cost.json"))
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, commit in (("old (run-cache)", args.old), ("new (persist)", args.new)):
            dest = Path(tmp) / label.split()[0]
            env = _copy(commit, dest)
            base = ["scale=fixture"]
            _repro(dest, env, base)
            changed_s, _, _ = _repro(dest, env, base + ["train.lr=0.0002"])
            back_s, ran, out = _repro(dest, env, base)
            restored = sorted(set(re.findall(r"Stage '([\w@-]+)' is cached - skipping run, checking out outputs",
                                             out)))
            rows.append({"variant": label, "commit": commit, "changed_lr_s": round(changed_s, 1),
                         "back_to_first_s": round(back_s, 1), "ran": sorted(ran), "restored_from_run_cache": restored})
    print(f"| variant | repro with train.lr changed (s) | repro back to the first settings (s) | re-ran | restored |")
    print("|---|---:|---:|---|---|")
    for r in rows:
        print(f"| {r['variant']} | {r['changed_lr_s']} | {r['back_to_first_s']} | {', '.join(r['ran']) or '—'} | "
              f"{', '.join(r['restored_from_run_cache']) or '—'} |")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
