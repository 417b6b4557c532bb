"""The oracle's candidates rendered at its matching size (`controllers.oracle.candidate_render: match`) against the
camera's full size (`full`), on the render-once benchmark's window (test city tunnel-0 exit, 640x480, the default
oracle ladder, --before-s/--after-s around the portal). Three parts, each answering one question:

A. Images (physics, no NFM): for --frames frames spread over the window and every exposure of the ladder (0 dB), the
   candidate image as the oracle's matcher reads it (grey, resized to the ORB working size as OrbFrontEnd does), full
   against match: median |difference| and mean difference (8-bit DN), and the ratio of ORB feature counts.
B. Decisions, open loop: the full-size oracle drives the window (its own warm-up); a twin with candidate_render
   match scores the same frame t at every step. Fraction of steps whose command is identical, and the size of the
   difference (EV of exposure, dB of gain) where it is not.
C. Closed loop and speed: evaluate on the window with all seven controllers (evaluate_render_once's setup, one
   process per variant, in process, one thread): the code at --old-ref (before render once), this checkout with
   `full` and with `match`. CPU seconds, the rows of every run but the oracle's compared with `full`, and the
   oracle's median NFM per (section, front end) against its bootstrap standard error; VO success.

    .venv/bin/python benchmarks/archive/oracle_candidate_render.py --frames 12 --old-ref f21af75
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path[:0] = [str(ROOT / "src"), str(ROOT), str(ROOT / "benchmarks"), str(ROOT / "tests")]


def _window(args, project: Path):
    from evaluate_render_once import bench_config
    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.evaluation.runner import _traversal_cached, plan_windows
    from expoctl.sim.closed_loop import RouteScene, make_sensors
    from expoctl.sim.oracle import CachedScene
    from expoctl.world import load_city_cached

    cfg = bench_config(project, args)
    inputs = EvaluationInputs.from_resolved(cfg)
    (w,) = plan_windows(inputs, project)
    city = load_city_cached(w.city, w.city_dir)
    traj = _traversal_cached(city, w, inputs.rig.fps)
    scene = CachedScene(RouteScene(city, traj, inputs.rig, inputs.render), keep_frames=2)
    sensors, _ = make_sensors(inputs.sensor, inputs.render, 1, inputs.evaluate.sensor_randomisation, w.seed)
    return cfg, inputs, w, scene, sensors[0].remember_noise()


def images(args, w, scene, sensor) -> list[dict]:
    """Part A."""
    import numpy as np

    from expoctl.features.pipeline import rgb_to_grey
    from expoctl.sim.closed_loop import sensor_rng
    from expoctl.sim.oracle import OracleController, OracleParams

    rows = []
    oracle = OracleController(scene, sensor, w.seed, w.traversal_frames, params=OracleParams(candidate_render="match"))
    for f in np.linspace(w.start, w.stop - 1, args.frames).round().astype(int):
        f = int(f)
        for e in OracleParams().exposures_us:
            full = scene.luminance(f, e, 1)
            k = oracle._coarse_factor(full.shape[1], full.shape[0])
            coarse = np.repeat(np.repeat(scene.luminance_coarse(f, e, 1, k), k, axis=0), k, axis=1)
            fe = oracle._frontend(full.shape[:2])
            greys = [fe.prepare(rgb_to_grey(sensor.capture(lum, e, 0.0, sensor_rng(w.seed, 1, f))))
                     for lum in (full, coarse)]
            d = greys[1].astype(np.float64) - greys[0].astype(np.float64)
            n = [fe.n_features(fe.extract(rgb_to_grey(sensor.capture(lum, e, 0.0, sensor_rng(w.seed, 1, f)))))
                 for lum in (full, coarse)]
            rows.append({"frame": f, "exposure_us": e, "factor": k, "median_abs_dn": float(np.median(np.abs(d))),
                         "mean_abs_dn": float(np.abs(d).mean()),
                         "mean_dn": float(d.mean()), "p99_abs_dn": float(np.percentile(np.abs(d), 99)),
                         "features_full": n[0], "features_match": n[1]})
        print(f"A: frame {f} done", flush=True)
    return rows


def decisions(args, w, scene, sensor) -> list[dict]:
    """Part B."""
    import math

    from expoctl.controllers.base import Controller, Settings
    from expoctl.sim.closed_loop import run_closed_loop
    from expoctl.sim.oracle import OracleController, OracleParams

    warmup = OracleParams().warmup_frames
    first = max(0, w.start - warmup)
    full = OracleController(scene, sensor, w.seed, w.traversal_frames, first, OracleParams(candidate_render="full"))
    twin = OracleController(scene, sensor, w.seed, w.traversal_frames, first, OracleParams(candidate_render="match"))
    rows = []

    class Both(Controller):
        name = "oracle"

        def reset(self, initial):
            full.reset(initial)
            twin.reset(initial)

        def update(self, image, applied):
            a, b = full.update(image, applied), twin.update(image, applied)
            rows.append({"same": a == b, "d_ev": abs(math.log2(b.exposure_us / a.exposure_us)),
                         "d_gain_db": abs(b.gain_db - a.gain_db)})
            return a

    for _ in run_closed_loop(scene, [sensor], Both(), Settings(0.0, 5000.0), range(w.start, w.stop), w.seed,
                             warmup_frames=warmup):
        pass
    return rows


def closed_loop(args, cfg, tmp: Path) -> dict:
    """Part C."""
    import numpy as np
    import pandas as pd
    from evaluate_render_once import CLOCK, COUNTERS, run_variant

    old = tmp / "old"
    subprocess.run(["git", "worktree", "add", "--detach", "-f", str(old), args.old_ref], cwd=ROOT, check=True,
                   capture_output=True)
    project = tmp / "project"
    times, outs = {}, {}
    try:
        for name, code, mode in (("old", old, None), ("full", ROOT, "full"), ("match", ROOT, "match")):
            c = json.loads(json.dumps(cfg))
            if mode is None:  # the code before render once knows neither key
                c["evaluate"].pop("share_render", None)
            if mode:
                c["controllers"]["oracle"] = {**(c["controllers"].get("oracle") or {}), "candidate_render": mode}
            config = tmp / f"config-{name}.json"
            config.write_text(json.dumps(c))
            outs[name] = tmp / f"out-{name}"
            times[name] = run_variant(code, project, config, outs[name])
            print(f"C: {name}: {times[name]}", flush=True)
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=ROOT, capture_output=True)
    drop = list(CLOCK + COUNTERS)
    res: dict = {"times": times}
    for table in ("frames", "runs"):
        a, b = (pd.read_parquet(outs[n] / "eval" / f"{table}.parquet") for n in ("full", "match"))
        a, b = (x[x.controller != "oracle"].drop(columns=[c for c in drop if c in x]).reset_index(drop=True)
                for x in (a, b))
        res[f"{table}_identical_except_oracle"] = bool(a.equals(b))
    fa, fb = (pd.read_parquet(outs[n] / "eval/frames.parquet") for n in ("full", "match"))
    fa, fb = (x[x.controller == "oracle"].sort_values("frame") for x in (fa, fb))
    res["oracle_settings_identical_frac"] = float(np.mean((fa.exposure_us.values == fb.exposure_us.values)
                                                          & (fa.gain_db.values == fb.gain_db.values)))
    rng = np.random.default_rng(0)
    nfm = []
    for kind, g in fa.groupby("section"):
        h = fb[fb.section == kind]
        for fe in ("orb", "viso"):
            x, y = g[f"nfm_{fe}"].dropna().values, h[f"nfm_{fe}"].dropna().values
            if len(x) < 3:
                continue
            boots = [np.median(rng.choice(x, len(x))) for _ in range(500)]
            nfm.append({"section": kind, "frontend": fe, "median_full": float(np.median(x)),
                        "median_match": float(np.median(y)), "delta": float(np.median(y) - np.median(x)),
                        "bootstrap_se": float(np.std(boots))})
    res["oracle_nfm"] = nfm
    ra, rb = (pd.read_parquet(outs[n] / "eval/runs.parquet") for n in ("full", "match"))
    res["vo_full"] = dict(zip(ra.controller, ra.vo_success.astype(bool).tolist()))
    res["vo_match"] = dict(zip(rb.controller, rb.vo_success.astype(bool).tolist()))
    return res


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=12, help="part A: frames spread over the window")
    ap.add_argument("--before-s", type=float, default=2.0)
    ap.add_argument("--after-s", type=float, default=2.0)
    ap.add_argument("--warmup", type=int, default=30, help="part C: warm-up frames of the causal controllers")
    ap.add_argument("--old-ref", default="f21af75", help="part C: the code before render once")
    ap.add_argument("--parts", default="ABC")
    ap.add_argument("--out", default=str(ROOT / "benchmarks/archive/results/oracle_candidate_render.json"))
    args = ap.parse_args()
    import numpy as np

    from bench_meta import run_metadata

    out: dict = {"args": vars(args), **run_metadata()}
    with tempfile.TemporaryDirectory(prefix="oracle-candidates-") as tmp:
        tmp = Path(tmp)
        cfg, inputs, w, scene, sensor = _window(args, tmp / "project")
        if "A" in args.parts:
            rows = images(args, w, scene, sensor)
            out["images"] = rows
            _write(args.out, out)
            print("\n| exposure µs | median |Δ grey| DN (median over frames) | mean |Δ| DN | mean Δ DN | p99 |Δ| DN | "
                  "features match / full |")
            print("|---:|---:|---:|---:|---:|---:|")
            for e in sorted({r["exposure_us"] for r in rows}):
                s = [r for r in rows if r["exposure_us"] == e]
                ratio = sum(r["features_match"] for r in s) / max(1, sum(r["features_full"] for r in s))
                print(f"| {e:.0f} | {statistics.median(r['median_abs_dn'] for r in s):.2f} | "
                      f"{statistics.median(r['mean_abs_dn'] for r in s):.2f} | "
                      f"{statistics.median(r['mean_dn'] for r in s):+.2f} | "
                      f"{statistics.median(r['p99_abs_dn'] for r in s):.1f} | {ratio:.3f} |")
        if "B" in args.parts:
            rows = decisions(args, w, scene, sensor)
            diff = [r for r in rows if not r["same"]]
            out["decisions"] = {"steps": len(rows), "identical": len(rows) - len(diff),
                                "identical_frac": (len(rows) - len(diff)) / max(1, len(rows)),
                                "d_ev_median_where_different": statistics.median(r["d_ev"] for r in diff) if diff else 0.0,
                                "d_ev_max": max((r["d_ev"] for r in diff), default=0.0),
                                "d_gain_db_max": max((r["d_gain_db"] for r in diff), default=0.0)}
            print("\nB:", json.dumps(out["decisions"]))
            _write(args.out, out)
        if "C" in args.parts:
            out["closed_loop"] = res = closed_loop(args, cfg, tmp)
            t = res["times"]
            print(f"\nC: CPU s old {t['old']['cpu_s']:.1f}, full {t['full']['cpu_s']:.1f}, match {t['match']['cpu_s']:.1f};"
                  f" old/full {t['old']['cpu_s'] / t['full']['cpu_s']:.2f}x, old/match "
                  f"{t['old']['cpu_s'] / t['match']['cpu_s']:.2f}x, full/match {t['full']['cpu_s'] / t['match']['cpu_s']:.2f}x")
            print("C:", json.dumps({k: v for k, v in res.items() if k != "times"}, indent=1))
    _write(args.out, out)
    print("→", args.out)
    del np


def _write(path: str, out: dict) -> None:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(out, indent=2, default=float) + "\n")


if __name__ == "__main__":
    main()
