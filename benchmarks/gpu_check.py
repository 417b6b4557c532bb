"""GPU check, prepared for a host with a GPU (issue 47, item 3): the EGL render back end at 640×480 and 1280×960 against
the numba ray caster on the same frames, and training samples/s with `train.device=cuda` at scale=paper's 224 px
network.

    PYTHONPATH=src python3.12 benchmarks/gpu_check.py [--frames 8] [--sizes 640x480,1280x960] [--epochs 2]
                                                      [--threads 16] [--out DIR] [--tiny]

What it reports, per part:
- the devices: torch's CUDA device (or none) and the OpenGL renderer string of the headless EGL context; llvmpipe /
  softpipe is Mesa's CPU rasteriser, i.e. no GPU behind EGL;
- render: per size, numba and egl alternating on the same frames of the train city's traversal 0 (open road, portals,
  tunnel interior): medians of the sharp render and of the render + 5 ms fast blur (glare included), frames/s, the
  egl/numba ratio, and the share of pixels whose surface code agrees (the back ends agree to float32 rounding);
- train: `benchmarks/train_cost.measure` at 224 px (conf/model and conf/train defaults, batch 64, on the synthetic
  image store of tests.support.synthetic_data) with train.device cuda: training samples/s and validation samples/s.

Without a GPU it says so for each part. `--tiny` (or no GPU at all) runs what can run here at a token size, so the
script itself is checked: the render part at 64×48 on 2 frames (egl on llvmpipe when there is an EGL context), the
train part on the CPU for one epoch of a small synthetic set. Timings from a tiny run mean nothing.
Writes gpu_check.json into --out (default: $OUT when set, else benchmarks/results/ for a GPU run and the system's
temporary directory for a tiny one).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "benchmarks", ROOT / "src"):  # tests.support, train_cost, expoctl (when not on PYTHONPATH)
    if str(p) not in sys.path:
        sys.path.append(str(p))

from expoctl.world import RenderConfig, Renderer, load_city  # noqa: E402


def cuda_device() -> str | None:
    """Name of torch's CUDA device 0, or None (no torch build with CUDA, or no device)."""
    try:
        import torch
    except ImportError:
        return None
    return torch.cuda.get_device_name(0) if torch.cuda.is_available() else None


def gl_renderer_string() -> tuple[str | None, str | None]:
    """(GL_RENDERER of a headless EGL context, or None; why not)."""
    try:
        from expoctl.world.gl_renderer import gl_context
        return str(gl_context().info.get("GL_RENDERER")), None
    except Exception as exc:  # no moderngl, no EGL: the render part runs numba only
        return None, f"{type(exc).__name__}: {exc}"


def is_software_gl(name: str | None) -> bool:
    return name is None or any(s in name.lower() for s in ("llvmpipe", "softpipe", "swrast", "lavapipe"))


def render_part(sizes: list[tuple[int, int]], n_frames: int, with_egl: bool) -> dict:
    from expoctl.world.gl_renderer import GLRenderer

    city = load_city("train")
    traj = city.traversal(0, None, fps=15.0, seed=0)
    frames = np.linspace(1, len(traj.poses) - 2, n_frames).astype(int)
    out = {}
    for w, h in sizes:
        cfg = RenderConfig(width=w, height=h, hfov_deg=70.0)  # 70°: the field of benchmarks/simulator_speed.py's rows
        rend = {"numba": Renderer(city, cfg, conditions=traj.conditions)}
        if with_egl:
            rend["egl"] = GLRenderer(city, cfg, conditions=traj.conditions)
        for r in rend.values():  # JIT / shader compile and atlas upload outside the timings
            r.render_exposure(traj, int(frames[0]), 5000.0)
        times = {name: [] for name in rend}
        agree = []
        for i, k in enumerate(frames):
            order = list(rend) if i % 2 == 0 else list(rend)[::-1]
            codes = {}
            for name in order:
                r = rend[name]
                t = time.perf_counter()
                codes[name] = r.render_full(traj.poses[k])["code"]
                sharp = time.perf_counter() - t
                r._cache.clear()
                t = time.perf_counter()
                r.render_exposure(traj, int(k), 5000.0)
                times[name].append((sharp, time.perf_counter() - t))
            if "egl" in codes:
                agree.append(float(np.mean(codes["egl"] == codes["numba"])))
        row = {}
        for name, v in times.items():
            med = 1e3 * np.median(np.array(v), axis=0)
            row[name] = {"sharp_ms": round(float(med[0]), 2), "blur_5ms_ms": round(float(med[1]), 2),
                         "frames_per_s_blur_5ms": round(1e3 / float(med[1]), 2)}
        if "egl" in row:
            row["egl_over_numba"] = {k: round(row["egl"][k] / row["numba"][k], 3) for k in ("sharp_ms", "blur_5ms_ms")}
            row["code_agreement_min"] = round(min(agree), 5)
        out[f"{w}x{h}"] = row
        print(f"render {w}x{h}, {len(frames)} frames: " + "; ".join(
            f"{n} sharp {r['sharp_ms']:.1f} ms, + 5 ms blur {r['blur_5ms_ms']:.1f} ms ({r['frames_per_s_blur_5ms']:.1f} f/s)"
            for n, r in row.items() if n in rend)
            + (f"; egl/numba {row['egl_over_numba']}; codes agree on >= {100 * row['code_agreement_min']:.2f} %"
               if "egl" in row else ""))
    return out


def train_part(device: str, epochs: int, threads: int, tiny: bool) -> dict:
    import torch
    from tests.support.synthetic_data import make_synthetic_dataset
    from train_cost import STORE_HW, measure

    n_seq, n_frames = (6, 6) if tiny else (6, 40)
    with tempfile.TemporaryDirectory() as tmp:
        paths = make_synthetic_dataset(Path(tmp), n_sequences=n_seq, n_frames=n_frames, hw=STORE_HW, seed=0)
        r = measure(224, paths, epochs, threads, device)
    train = float(np.median(r["train_s_per_sample_each_epoch"]))
    val = float(np.median(r["val_s_per_sample_each_epoch"]))
    row = {"device": device, "torch": torch.__version__, "input_size": 224, "epochs": r["epochs"],
           "n_train_samples": r["n_train_samples"], "batch_size": r["batch_size"],
           "train_samples_per_s": round(1.0 / train, 1), "val_samples_per_s": round(1.0 / max(val, 1e-9), 1),
           "macs_per_sample": r["macs_per_sample"]}
    print(f"train 224 px on {device}: {row['train_samples_per_s']} training samples/s, "
          f"{row['val_samples_per_s']} validation samples/s ({r['n_train_samples']} samples, {r['epochs']} epochs)")
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--sizes", default="640x480,1280x960")
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1, help="numba and torch CPU threads")
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--tiny", action="store_true", help="token sizes (checks the script, not the speed)")
    args = ap.parse_args()

    import numba
    numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    cuda = cuda_device()
    gl_name, gl_why = gl_renderer_string()
    gpu_gl = not is_software_gl(gl_name)
    tiny = args.tiny or not (cuda or gpu_gl)
    print(f"python {platform.python_version()}; CUDA device: {cuda or 'none'}; EGL OpenGL renderer: "
          f"{gl_name or 'none (' + str(gl_why) + ')'}" + ("" if gpu_gl else " — no GPU behind EGL"))
    if not cuda and not gpu_gl:
        print("no GPU found: running the CPU parts at token size only (--tiny); these timings say nothing")
    result = {"python": platform.python_version(), "cpu_count": os.cpu_count(), "cuda_device": cuda,
              "gl_renderer": gl_name, "gl_error": gl_why, "gpu_behind_egl": gpu_gl, "tiny": tiny,
              "numba_threads": numba.get_num_threads()}

    sizes = [(64, 48)] if tiny and not gpu_gl else [tuple(int(v) for v in s.lower().split("x")) for s in args.sizes.split(",")]
    n_frames = 2 if tiny and not gpu_gl else args.frames
    result["render"] = render_part(sizes, n_frames, with_egl=gl_name is not None)
    if not gpu_gl:
        result["render_note"] = "no GPU behind EGL: egl ran on " + (gl_name or "nothing (numba only)")

    if cuda:
        result["train"] = train_part("cuda", args.epochs, args.threads, tiny=False)
    else:
        print("train.device=cuda: no CUDA device; one tiny epoch on the CPU instead")
        result["train"] = train_part("cpu", 1, min(args.threads, 2), tiny=True)
        result["train_note"] = "no CUDA device: CPU, tiny"

    out_dir = args.out or (Path(os.environ["OUT"]) if os.environ.get("OUT") else
                           (ROOT / "benchmarks" / "results" if not tiny else Path(tempfile.gettempdir())))
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "gpu_check.json").write_text(json.dumps(result, indent=1) + "\n")
    print(f"wrote {out_dir / 'gpu_check.json'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
