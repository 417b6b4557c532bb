"""What the pinned numeric mode costs against the unpinned one (`numerics.mode: host`), stage by stage (issue 46).

    .venv/bin/python benchmarks/numerics_cost.py --project /tmp/x [--warmup-rounds 1] [--rounds 1] [--micro-repeats 3]

Two parts, each mode in its own processes, one after the other on this host (docs/reproducibility.md has the rule
that decides the default, written before this was run):

- **micro**: what dominates the default scale, in a fresh process per mode and repeat, with the mode's environment
  (expoctl.numerics.environment) set before any import: rendering (`render`: the numba ray caster and 5 ms motion
  blur at 640x480, one exposure per frame, median over frames after one warm-up frame that compiles or loads the
  kernels) and training (`train epoch`: benchmarks/train_cost.py at 64 px on 2 threads, its train s/sample).
- **fixture DAG**: `--project` is a fixture-scale project (a clone with ../shared beside it); every round runs
  `dvc repro` there once per mode (`numerics` is a param of every computing stage, so each switch re-runs the whole
  DAG) and reads each stage's `stage_seconds` from the project's MLflow store. A warm-up round compiles the numba
  kernels of each mode (the cache is keyed by the target CPU, and the pinned mode's is haswell) and is reported but
  not compared (`--warmup-rounds 0` for a project whose caches are warm for both modes: it ran both already); the
  comparison is the median of the other rounds. The project's params.yaml is restored at the end.

Prints a table and writes benchmarks/results/numerics_cost.json.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "src"), str(ROOT / "benchmarks")]

from bench_meta import run_metadata  # noqa: E402
from expoctl.numerics import PINNED_ENV, NumericsConfig, environment, library_versions  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results" / "numerics_cost.json"
MODES = ("pinned", "host")
#: the end-to-end test's fixture run (tests/pipeline/fixture_manifest.py OVERRIDES)
FIXTURE = ["scale=fixture", "iteration3.enabled=true", "select_model.enabled=true"]


def mode_env(mode: str) -> dict[str, str]:
    """This process's environment with the mode's variables only (none of the pins inherited from the shell)."""
    env = {k: v for k, v in os.environ.items() if k not in PINNED_ENV}
    env.update(environment(NumericsConfig(mode)))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(ROOT)])
    return env


def render_child(frames: int) -> dict:
    from expoctl.world import load_city
    from expoctl.world.render_config import RenderConfig
    from expoctl.world.renderer import Renderer

    city = load_city("train")
    traj = city.traversal(0, None, fps=15.0, seed=0)
    r = Renderer(city, RenderConfig(width=640, height=480), traj.conditions)
    times = []
    for k in range(frames + 1):  # the first frame compiles or loads the kernels
        t0 = time.perf_counter()
        r.render_exposure(traj, 20 + 5 * k, 5000.0)
        times.append(time.perf_counter() - t0)
    return {"first_frame_s": times[0], "s_per_frame": statistics.median(times[1:]), "frames": frames}


def micro(mode: str, repeats: int, frames: int) -> dict:
    out: dict = {"render_s_per_frame": [], "render_first_frame_s": [], "train_s_per_sample": []}
    env = mode_env(mode)
    for _ in range(repeats):
        p = subprocess.run([sys.executable, __file__, "--child-render", str(frames)], env=env, capture_output=True,
                           text=True)
        line = next((ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")), None)
        if line is None:
            raise RuntimeError(f"render child ({mode}) failed:\n{p.stderr[-2000:]}")
        r = json.loads(line[7:])
        out["render_s_per_frame"].append(r["s_per_frame"])
        out["render_first_frame_s"].append(r["first_frame_s"])
        with tempfile.TemporaryDirectory() as tmp:
            res = Path(tmp) / "train.json"
            p = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "train_cost.py"), "--sizes", "64",
                                "--repeats", "1", "--epochs", "3", "--out", str(res)], env=env, capture_output=True,
                               text=True)
            if p.returncode != 0:
                raise RuntimeError(f"train_cost ({mode}) failed:\n{p.stderr[-2000:]}")
            out["train_s_per_sample"].append(json.loads(res.read_text())["rows"][0]["train_s_per_sample"])
    out["render_median"] = statistics.median(out["render_s_per_frame"])
    out["train_median"] = statistics.median(out["train_s_per_sample"])
    return out


def stage_seconds(project: Path, since_ms: int) -> dict[str, float]:
    import mlflow

    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{project / 'mlflow.db'}")
    exp = client.get_experiment_by_name("expoctl")
    out = {}
    for r in client.search_runs([exp.experiment_id], filter_string=f"attributes.start_time >= {since_ms}",
                                max_results=5000):
        if "mlflow.parentRunId" in r.data.tags or "stage_seconds" not in r.data.metrics:
            continue
        out[r.data.tags["stage"]] = r.data.metrics["stage_seconds"]
    return out


def dag(project: Path, mode: str) -> dict:
    import yaml

    (project / "params.yaml").write_text(yaml.safe_dump({"overrides": FIXTURE + [f"numerics.mode={mode}"]}))
    env = {k: v for k, v in os.environ.items() if k not in PINNED_ENV}  # the stages pin themselves (or not)
    env.update(PATH=f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}",
               PYTHONPATH=os.pathsep.join([str(project / "src"), str(project)]),
               MLFLOW_TRACKING_URI=f"sqlite:///{project / 'mlflow.db'}")
    since = int(time.time() * 1000)
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "dvc", "repro"], cwd=project, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"dvc repro ({mode}) failed:\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}")
    stages = stage_seconds(project, since)
    return {"wall_s": wall, "stages": stages, "sum_stage_s": sum(stages.values())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--project", type=Path, help="a fixture-scale project clone (omit: micro-benchmarks only)")
    ap.add_argument("--warmup-rounds", type=int, default=1, help="DAG rounds first run, not compared (numba compiles)")
    ap.add_argument("--rounds", type=int, default=1, help="DAG rounds compared")
    ap.add_argument("--micro-repeats", type=int, default=3)
    ap.add_argument("--frames", type=int, default=4, help="timed render frames per process")
    ap.add_argument("--child-render", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child_render:
        print("RESULT " + json.dumps(render_child(args.child_render)))
        return 0

    result: dict = {**run_metadata(), "versions": library_versions(), "micro": {}, "dag": []}
    for mode in MODES:
        result["micro"][mode] = micro(mode, args.micro_repeats, args.frames)
        print(f"micro {mode}: render {result['micro'][mode]['render_median']:.3f} s/frame, train "
              f"{result['micro'][mode]['train_median'] * 1e3:.3f} ms/sample", flush=True)
    if args.project:
        saved = (args.project / "params.yaml").read_text()
        try:
            for k in range(args.warmup_rounds + args.rounds):
                for mode in MODES:
                    run = {"round": k, "warmup": k < args.warmup_rounds, "mode": mode, **dag(args.project, mode)}
                    result["dag"].append(run)
                    print(f"round {k} {mode}: {run['wall_s']:.0f} s wall, {run['sum_stage_s']:.0f} s in stages",
                          flush=True)
        finally:
            (args.project / "params.yaml").write_text(saved)

    m = result["micro"]
    rows = [("render, s per 640x480 frame", m["pinned"]["render_median"], m["host"]["render_median"]),
            ("train epoch, s per sample (64 px)", m["pinned"]["train_median"], m["host"]["train_median"])]
    compared = [r for r in result["dag"] if not r["warmup"]]
    if compared:
        med = {mode: {} for mode in MODES}
        for mode in MODES:
            runs = [r for r in compared if r["mode"] == mode]
            for stage in sorted(runs[0]["stages"]):
                med[mode][stage] = statistics.median(r["stages"].get(stage, float("nan")) for r in runs)
            med[mode]["(sum of stages)"] = statistics.median(r["sum_stage_s"] for r in runs)
            med[mode]["(dvc repro wall)"] = statistics.median(r["wall_s"] for r in runs)
        result["dag_median"] = med
        rows += [(f"fixture {stage}", med["pinned"][stage], med["host"].get(stage, float("nan")))
                 for stage in med["pinned"]]
    result["table"] = [{"what": w, "pinned": p, "host": h, "pinned_over_host": p / h if h else None}
                       for w, p, h in rows]
    print(f"\n{'measure':38s} {'pinned':>10s} {'host':>10s} {'pinned/host':>12s}")
    for w, p, h in rows:
        print(f"{w:38s} {p:>10.4f} {h:>10.4f} {p / h if h else float('nan'):>12.3f}")
    from expoctl.io import write_json

    write_json(result, RESULTS)
    print(f"wrote {RESULTS.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
