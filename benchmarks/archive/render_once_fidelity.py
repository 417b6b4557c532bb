"""How close each fast motion blur is to the sub-frame reference: `share_render: false` (a sharp render at each
exposure's mid-point, smeared ±half its flow) and `true` (one sharp render at the frame start, smeared along the
whole flow), against `blur: reference` (the exposure averaged over sub-frame renders, < 0.5 px apart).

A physics check that does not look at NFM or VO: for frames of the render-once benchmark's window (test city
tunnel-0 exit, 640×480, --seed's traversal) and a ladder of exposure times, it renders the scene luminance three
ways and reports, per exposure: the relative RMS error of each fast image against the reference (on log luminance,
which is what an 8-bit image after the camera response resolves), and the fine-detail energy ratio (mean squared
Laplacian of log luminance, fast / reference: < 1 means the fast image is smoother than the reference).

    .venv/bin/python benchmarks/archive/render_once_fidelity.py --frames 8 --exposures-us 100 500 2000 8000
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]  # this file is benchmarks/archive/<name>.py
sys.path.append(str(ROOT / "benchmarks"))  # bench_meta, the helper it shares with the live benchmarks
sys.path[:0] = [str(ROOT / "src"), str(ROOT), str(ROOT / "benchmarks")]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--frames", type=int, default=8, help="frames spread evenly over the window")
    ap.add_argument("--exposures-us", type=float, nargs="+", default=[100.0, 500.0, 2000.0, 8000.0])
    ap.add_argument("--before-s", type=float, default=2.0)
    ap.add_argument("--after-s", type=float, default=2.0)
    ap.add_argument("--warmup", type=int, default=30)
    ap.add_argument("--out", default=str(ROOT / "benchmarks/archive/results/render_once_fidelity.json"))
    args = ap.parse_args()

    import cv2
    import numpy as np
    from dataclasses import replace

    from bench_meta import run_metadata
    from evaluate_render_once import bench_config
    from expoctl.evaluation.inputs import EvaluationInputs
    from expoctl.evaluation.runner import _traversal_cached, plan_windows
    from expoctl.world import load_city_cached
    from expoctl.world.backends import make_renderer

    with tempfile.TemporaryDirectory(prefix="render-once-fidelity-") as tmp:
        project = Path(tmp) / "project"
        cfg = bench_config(project, args)
        cfg["seed"] = args.seed
        inputs = EvaluationInputs.from_resolved(cfg)
        (w,) = plan_windows(inputs, project)
        city = load_city_cached(w.city, w.city_dir)
        traj = _traversal_cached(city, w, inputs.rig.fps)
        base = inputs.world.render
        renderers = {name: make_renderer(city, replace(base, blur=blur, share_render=share))
                     for name, blur, share in (("reference", "reference", False), ("share_render false", "fast", False),
                                               ("share_render true", "fast", True))}
        frames = np.linspace(w.start, w.stop - 1, args.frames).round().astype(int)
        rows = []
        for f in frames:
            for e in args.exposures_us:
                logs = {k: np.log(np.maximum(r.render_exposure(traj, int(f), e).mean(axis=2, dtype=np.float64), 1e-4))
                        for k, r in renderers.items()}
                ref = logs.pop("reference")
                lap_ref = float(np.mean(cv2.Laplacian(ref, cv2.CV_64F) ** 2))
                for k, img in logs.items():
                    rows.append({"frame": int(f), "exposure_us": e, "variant": k,
                                 "rms_log_error": float(np.sqrt(np.mean((img - ref) ** 2))),
                                 "detail_ratio": float(np.mean(cv2.Laplacian(img, cv2.CV_64F) ** 2)) / lap_ref})
            print(f"frame {f} done", flush=True)
    summary = []
    print("\n| exposure µs | variant | RMS log-luminance error vs reference (median over frames) | "
          "fine-detail energy / reference (median) |")
    print("|---|---|---|---|")
    for e in args.exposures_us:
        for k in ("share_render false", "share_render true"):
            sel = [r for r in rows if r["exposure_us"] == e and r["variant"] == k]
            s = {"exposure_us": e, "variant": k,
                 "rms_log_error_median": float(np.median([r["rms_log_error"] for r in sel])),
                 "detail_ratio_median": float(np.median([r["detail_ratio"] for r in sel]))}
            summary.append(s)
            print(f"| {e:g} | {k} | {s['rms_log_error_median']:.4f} | {s['detail_ratio_median']:.3f} |")
    out = {"summary": summary, "rows": rows, "window": w.sequence, "args": vars(args), **run_metadata()}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2) + "\n")
    print("→", args.out)


if __name__ == "__main__":
    main()
