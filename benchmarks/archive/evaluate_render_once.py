"""Old vs new evaluate, side by side in one run: per-run rendering (the code at --old-ref, checked out in a git
worktree) against render once per window (this checkout), with evaluate.share_render false and true.

Every variant evaluates the same plan in this process's machine, one after the other, alternating old and new:
the default scale's evaluate (640×480, all seven controllers, the default oracle grid) on the test city's tunnel-0
exit window, shortened (--before-s/--after-s around the portal, --warmup frames; the oracle's own 10) so a
repetition takes minutes. Each variant runs in its own Python process, in process (no worker pool: CPU time is the
work), with the fixture project's train frames (SumLog tuning) and its small untrained network as `learned`.

Printed and written (--out): wall and CPU seconds per variant (medians over --reps), the ratios, and what changed:
frames.parquet / runs.parquet old vs new with share_render false must be equal except for clock columns and the
render counters (the registered prediction: bit-identical); with share_render true, per controller and section kind,
the median NFM deltas against the old code next to the median's bootstrap standard error over frames.

    .venv/bin/python benchmarks/archive/evaluate_render_once.py --old-ref f21af75 --reps 2

--paired-seeds K asks a second question with this checkout only: is a NFM delta of share_render true against
false a bias, or a closed loop amplifying a small change? For K top-level seeds (each its own traversal, sun, sky
and sensor noise) it runs both share_render values on the same window and writes the paired deltas per
(controller, front end), their mean and its standard error over seeds (--paired-out):

    .venv/bin/python benchmarks/archive/evaluate_render_once.py --paired-seeds 6 --controllers agae shin shim mean_intensity learned
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
CLOCK = ("controller_ms", "controller_ms_median", "seconds", "seconds_per_frame", "oracle_ms_median")
COUNTERS = ("oracle_renders", "window_renders", "window_sharp_renders", "window_noise_draws")


def child(code: Path, project: Path, config: Path, out: Path) -> None:
    """One evaluate in this process with the code under `code`; prints {"wall_s", "cpu_s"}."""
    sys.path[:0] = [str(code / "src"), str(code)]
    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.evaluation.runner import evaluate, write_outputs
    from expoctl.parallel import ParallelConfig

    cfg = json.loads(config.read_text())
    inputs = EvaluationInputs.from_resolved(cfg)
    t0 = time.perf_counter()
    r = resource.getrusage(resource.RUSAGE_SELF)
    result = evaluate(inputs, project, parallel=ParallelConfig("inprocess"))
    wall = time.perf_counter() - t0
    r2 = resource.getrusage(resource.RUSAGE_SELF)
    write_outputs(result, out)
    print(json.dumps({"wall_s": wall, "cpu_s": (r2.ru_utime + r2.ru_stime) - (r.ru_utime + r.ru_stime),
                      "max_rss_mb": r2.ru_maxrss / 1024}))


def bench_config(project: Path, args) -> dict:
    """The default scale's resolved config with the benchmark's window and the fixture project's paths."""
    sys.path[:0] = [str(ROOT), str(ROOT / "tests")]
    from eval_fixtures import make_fixture_project
    from stages.compose import compose_config

    fixture = make_fixture_project(project)
    cfg = compose_config([])
    cfg["paths"] = {**cfg["paths"], **{k: fixture["paths"][k] for k in ("frames", "model", "final_model")}}
    cfg["controllers"]["learned"] = {**(cfg["controllers"].get("learned") or {}), "checkpoint": fixture["paths"]["model"]}
    cfg["evaluate"]["splits"] = {"test": {"first_traversal": 0, "n_traversals": 1, "window": "portal",
                                          "before_s": args.before_s, "after_s": args.after_s, "windows": [1]}}
    cfg["evaluate"]["warmup_frames"] = args.warmup
    cfg["evaluate"]["sumlog_pairs"] = 3
    cfg["evaluate"]["n_jobs"] = 1
    cfg["features"]["sumlog"]["max_pairs"] = 3
    return cfg


def run_variant(code: Path, project: Path, config: Path, out: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": "", "OMP_NUM_THREADS": "1", "NUMBA_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, __file__, "--child", str(code), str(project), str(config), str(out)],
                          capture_output=True, text=True, env=env, cwd=project)
    if proc.returncode != 0:
        raise SystemExit(f"variant {code} / {config.name} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def compare(old: Path, new: Path) -> dict:
    import numpy as np
    import pandas as pd

    out = {}
    for table in ("frames", "runs"):
        a, b = (pd.read_parquet(d / "eval" / f"{table}.parquet") for d in (old, new))
        drop = [c for c in CLOCK + COUNTERS]
        a, b = a.drop(columns=[c for c in drop if c in a]), b.drop(columns=[c for c in drop if c in b])
        same = a.shape == b.shape and list(a.columns) == list(b.columns) and a.equals(b)
        out[f"{table}_identical"] = bool(same)
    fa, fb = (pd.read_parquet(d / "eval/frames.parquet").sort_values(["controller", "frame"]) for d in (old, new))
    out["settings_identical_frac"] = float(np.mean((fa.exposure_us.values == fb.exposure_us.values)
                                                   & (fa.gain_db.values == fb.gain_db.values)))
    out["mean_grey_abs_diff_median"] = float(np.median(np.abs(fa.mean_grey.values - fb.mean_grey.values)))
    rng = np.random.default_rng(0)
    rows = []
    for (ctrl, kind), g in fa.groupby(["controller", "section"]):
        h = fb[(fb.controller == ctrl) & (fb.section == kind)]
        for fe in ("orb", "viso"):
            x, y = g[f"nfm_{fe}"].dropna().values, h[f"nfm_{fe}"].dropna().values
            if len(x) < 3:
                continue
            boots = [np.median(rng.choice(x, len(x))) for _ in range(500)]
            rows.append({"controller": ctrl, "section": kind, "frontend": fe, "n_pairs": int(len(x)),
                         "old_median_nfm": float(np.median(x)), "new_median_nfm": float(np.median(y)),
                         "delta": float(np.median(y) - np.median(x)), "bootstrap_se": float(np.std(boots))})
    out["nfm"] = rows
    ra, rb = (pd.read_parquet(d / "eval/runs.parquet").sort_values("run_id") for d in (old, new))
    out["vo_success_old"] = dict(zip(ra.controller, ra.vo_success.astype(bool).tolist()))
    out["vo_success_new"] = dict(zip(rb.controller, rb.vo_success.astype(bool).tolist()))
    return out


def paired_seeds(args) -> None:
    """share_render false vs true on --paired-seeds seeds (this checkout); paired NFM deltas per controller."""
    import numpy as np
    import pandas as pd

    sys.path[:0] = [str(ROOT)]
    from bench_meta import run_metadata

    rows, times = [], []
    with tempfile.TemporaryDirectory(prefix="render-once-paired-") as tmp:
        tmp = Path(tmp)
        project = tmp / "project"
        cfg = bench_config(project, args)
        cfg["evaluate"]["controllers"] = list(args.controllers)
        for k in range(args.paired_seeds):
            seed = int(cfg["seed"]) + 1 + k
            medians = {}
            for share in (False, True):
                c = json.loads(json.dumps(cfg))
                c["seed"], c["evaluate"]["share_render"] = seed, share
                config = tmp / f"config-{seed}-{share}.json"
                config.write_text(json.dumps(c))
                out = tmp / f"out-{seed}-{share}"
                res = run_variant(ROOT, project, config, out)
                times.append({"seed": seed, "share_render": share, **res})
                f = pd.read_parquet(out / "eval/frames.parquet")
                for ctrl in args.controllers:
                    for fe in ("orb", "viso"):
                        x = f.loc[f.controller == ctrl, f"nfm_{fe}"].dropna()
                        medians[(share, ctrl, fe)] = float(np.median(x)) if len(x) else float("nan")
            for ctrl in args.controllers:
                for fe in ("orb", "viso"):
                    a, b = medians[(False, ctrl, fe)], medians[(True, ctrl, fe)]
                    rows.append({"seed": seed, "controller": ctrl, "frontend": fe, "median_nfm_false": a,
                                 "median_nfm_true": b, "delta": b - a})
            print(f"seed {seed}: " + ", ".join(f"{r['controller']}/{r['frontend']} {r['delta']:+.0f}"
                                               for r in rows if r["seed"] == seed), flush=True)
    d = pd.DataFrame(rows)
    summary = []
    print(f"\n| controller | front end | mean Δ median NFM over {args.paired_seeds} seeds | SE | mean |Δ| | "
          "range of Δ |")
    print("|---|---|---|---|---|---|")
    for (ctrl, fe), g in d.groupby(["controller", "frontend"], sort=False):
        x = g.delta.to_numpy()
        se = float(np.std(x, ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")
        summary.append({"controller": ctrl, "frontend": fe, "mean_delta": float(np.mean(x)), "se": se,
                        "mean_abs_delta": float(np.mean(np.abs(x))), "min": float(x.min()), "max": float(x.max())})
        print(f"| {ctrl} | {fe} | {np.mean(x):+.1f} | {se:.1f} | {np.mean(np.abs(x)):.1f} | "
              f"{x.min():+.0f} … {x.max():+.0f} |")
    wall = {s: statistics.median(t["wall_s"] for t in times if t["share_render"] == s) for s in (False, True)}
    print(f"\nmedian wall per run: share_render false {wall[False]:.1f} s, true {wall[True]:.1f} s "
          f"({wall[False] / wall[True]:.2f}x)")
    out = {"paired": rows, "summary": summary, "times": times, "args": vars(args), **run_metadata()}
    Path(args.paired_out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.paired_out).write_text(json.dumps(out, indent=2) + "\n")
    print("→", args.paired_out)


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(*(Path(p) for p in sys.argv[2:6]))
        return
    ap = argparse.ArgumentParser()
    ap.add_argument("--old-ref", default="f21af75", help="the commit before render once (per-run rendering)")
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--before-s", type=float, default=2.0)
    ap.add_argument("--after-s", type=float, default=2.0)
    ap.add_argument("--warmup", type=int, default=30)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/archive/results/evaluate_render_once.json"))
    ap.add_argument("--paired-seeds", type=int, default=0,
                    help="instead: share_render false vs true on this many seeds (this checkout only)")
    ap.add_argument("--controllers", nargs="+", default=["agae", "shin", "shim", "mean_intensity", "learned"])
    ap.add_argument("--paired-out", default=str(ROOT / "benchmarks/archive/results/evaluate_render_once_paired.json"))
    args = ap.parse_args()
    if args.paired_seeds:
        paired_seeds(args)
        return
    sys.path[:0] = [str(ROOT)]
    from bench_meta import run_metadata

    with tempfile.TemporaryDirectory(prefix="render-once-") as tmp:
        tmp = Path(tmp)
        old_code = tmp / "old"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(old_code), args.old_ref],
                       check=True, capture_output=True)
        try:
            project = tmp / "project"
            cfg = bench_config(project, args)
            configs = {}
            for share in (False, True):
                c = json.loads(json.dumps(cfg))
                c["evaluate"]["share_render"] = share
                configs[share] = tmp / f"config-share-{share}.json"
                configs[share].write_text(json.dumps(c))
            old_cfg = json.loads(json.dumps(cfg))
            old_cfg["evaluate"].pop("share_render", None)  # the old code does not know the key
            (tmp / "config-old.json").write_text(json.dumps(old_cfg))
            variants = {"old (per run)": (old_code, tmp / "config-old.json"),
                        "new, share_render false": (ROOT, configs[False]),
                        "new, share_render true": (ROOT, configs[True])}
            times: dict[str, list[dict]] = {k: [] for k in variants}
            for rep in range(args.reps):
                for name, (code, config) in variants.items():
                    res = run_variant(code, project, config, tmp / f"out-{len(times[name])}-{name[:3]}{config.stem}")
                    times[name].append(res)
                    print(f"rep {rep}: {name:<26} {res['wall_s']:7.1f} s wall {res['cpu_s']:7.1f} s CPU "
                          f"{res['max_rss_mb']:6.0f} MB", flush=True)
            last = {name: tmp / f"out-{args.reps - 1}-{name[:3]}{config.stem}" for name, (_, config) in variants.items()}
            same = compare(last["old (per run)"], last["new, share_render false"])
            shared = compare(last["old (per run)"], last["new, share_render true"])
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(old_code)], check=False)
    med = {k: {m: statistics.median(r[m] for r in v) for m in ("wall_s", "cpu_s", "max_rss_mb")}
           for k, v in times.items()}
    base = med["old (per run)"]["wall_s"]
    print(f"\n| variant | wall s (median of {args.reps}) | CPU s | peak RSS MB | speed-up (wall) |")
    print("|---|---|---|---|---|")
    for k, m in med.items():
        print(f"| {k} | {m['wall_s']:.1f} | {m['cpu_s']:.1f} | {m['max_rss_mb']:.0f} | {base / m['wall_s']:.2f}x |")
    print(f"\nold vs new (share_render false): frames identical {same['frames_identical']}, runs identical "
          f"{same['runs_identical']}")
    print(f"old vs new (share_render true): settings identical on {shared['settings_identical_frac']:.1%} of frames, "
          f"median |Δ mean grey| {shared['mean_grey_abs_diff_median']:.2f} DN")
    print("| controller | section | front end | old median NFM | new | Δ | bootstrap SE |")
    print("|---|---|---|---|---|---|---|")
    for r in shared["nfm"]:
        print(f"| {r['controller']} | {r['section']} | {r['frontend']} | {r['old_median_nfm']:.0f} | "
              f"{r['new_median_nfm']:.0f} | {r['delta']:+.0f} | {r['bootstrap_se']:.1f} |")
    out = {"medians": med, "runs": times, "identity_share_false": same, "deltas_share_true": shared,
           "args": vars(args), **run_metadata()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print("→", args.out)


if __name__ == "__main__":
    main()
