"""Simulator speed: render (+ motion blur) (+ sensor, when expoctl.camera.sensor exists) frames/s per camera, and memory.

Usage: .venv/bin/python benchmarks/simulator_speed.py [--frames 12] [--width 640] [--height 480] [--threads 0]
                                                    [--baseline OLD_SRC] [--backend numba|egl|both]
                                                    [--sizes 640x480,320x240] [--lp-threads N]
Prints a table of medians over frames and writes benchmarks/results/simulator_speed.json.
--backend egl: the same table for the OpenGL backend (gl_renderer.GLRenderer on headless EGL).
--backend both: time numba and egl alternating on the same frames, at each of --sizes, stage by stage (sharp render,
+ 5 ms fast blur, + glare, + sensor), with egl/numba ratios and frames/s per camera; writes
benchmarks/results/simulator_speed_backends.json (--backend egl writes simulator_speed_egl.json).
--lp-threads: LP_NUM_THREADS for Mesa llvmpipe (set before the GL context exists; default: llvmpipe's own).
--baseline OLD_SRC: also time another version of the code (a `src` directory, e.g. from
`git archive <commit> src | tar -x -C /tmp/old` → /tmp/old/src) on the same frames, alternating with the current code
frame by frame, and report both medians, their ratio and whether the images are identical: on a shared machine only
ratios measured in one run compare.
Frames are spread over the training city's whole route (open road, portals, tunnel interior), so the numbers mix
scene types the way a traversal does. Each stage is timed per camera-frame (wall clock; the CPU-time rows show the
cost independent of other users of the machine); `total` = blurred render + sensor.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import sys
import time
import tracemalloc
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

import importlib  # noqa: E402
import re  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

from expoctl.io import write_json  # noqa: E402
from expoctl.world import Renderer, load_city  # noqa: E402


def _sensor(width, height):
    """The sensor helper's model if committed, else None."""
    try:
        from expoctl.camera.sensor import Sensor, SensorConfig
    except ImportError:
        return None, "expoctl.camera.sensor not available"
    import yaml
    cfg_path = ROOT / "conf" / "sensor" / "default.yaml"
    cfg = yaml.safe_load(cfg_path.read_text()) if cfg_path.is_file() else None
    try:
        return Sensor(SensorConfig.from_dict(cfg), height, width, 0), None
    except Exception as exc:  # report, do not hide: the table says why the sensor column is missing
        return None, f"Sensor() failed: {exc}"


def _load_baseline(src: str):
    """The `expoctl.world` of another source tree, imported as package `expoctl_baseline` (a renamed copy in a temp
    dir), so both versions run in this process on the same frames."""
    tmp = Path(tempfile.mkdtemp(prefix="expoctl_baseline_"))
    pkg = tmp / "expoctl_baseline"
    shutil.copytree(Path(src) / "expoctl", pkg, ignore=shutil.ignore_patterns("__pycache__"))
    for f in pkg.rglob("*.py"):
        text = re.sub(r"\bexpoctl\.", "expoctl_baseline.", f.read_text())
        f.write_text(text.replace("from expoctl import", "from expoctl_baseline import"))
    sys.path.insert(0, str(tmp))
    return importlib.import_module("expoctl_baseline.world")


def _time_render(renderer, traj, k):
    """(sharp render s, sharp CPU s, 5 ms blurred render s, luminance of the sharp render)."""
    t, c = time.perf_counter(), time.process_time()
    lum = renderer.render(traj.poses[k])[0]
    sharp, sharp_cpu = time.perf_counter() - t, time.process_time() - c
    renderer._cache.clear()
    t = time.perf_counter()
    renderer.render_exposure(traj, int(k), 5000.0)
    return sharp, sharp_cpu, time.perf_counter() - t, lum


STAGES = ("render_sharp", "smear_5ms", "glare", "sensor")
CUMULATIVE = (("sharp render", 1), ("+ 5 ms fast blur", 2), ("+ glare", 3), ("+ sensor", 4))


def _time_stages(r, traj, k, sensor, rng):
    """Per stage wall seconds for one camera-frame at 5 ms exposure: the stages of Renderer.render_exposure's fast
    path (sharp render at mid-exposure, smear, glare), then the sensor; plus the sharp image for a cross-check."""
    t0 = float(traj.timestamps_ns[k]) * 1e-9
    dur = 5000.0e-6
    ref = traj.pose_at(t0 + 0.5 * dur)
    out = []
    t = time.perf_counter()
    sharp = dict(r.render_full(ref, glare=False), pose=ref)
    out.append(time.perf_counter() - t)
    t = time.perf_counter()
    smeared, max_shift = r._smear(sharp, traj.pose_at(t0), traj.pose_at(t0 + dur))
    out.append(time.perf_counter() - t)
    t = time.perf_counter()
    lum = r.apply_glare(smeared if max_shift >= 0.5 else sharp["luminance"])
    out.append(time.perf_counter() - t)
    if sensor is not None:
        t = time.perf_counter()
        sensor.capture(lum, 5000.0, 6.0, rng)
        out.append(time.perf_counter() - t)
    return out, sharp


def compare_backends(args) -> int:
    """numba vs egl on the same frames, alternating which goes first, at each size; medians and egl/numba ratios."""
    from expoctl.world.gl_renderer import GLRenderer

    city = load_city(args.city)
    traj = city.traversal(0, None, fps=15.0, seed=0)
    frames = np.linspace(1, len(traj.poses) - 2, args.frames).astype(int)
    result = {"city": args.city, "frames": int(len(frames)), "numba_threads": numba.get_num_threads(),
              "lp_num_threads": os.environ.get("LP_NUM_THREADS"), "cpu_count": os.cpu_count(),
              "load_average_1min_start": os.getloadavg()[0], "python": platform.python_version(), "sizes": {}}
    for size in args.sizes.split(","):
        w, h = (int(v) for v in size.lower().split("x"))
        rend = {"numba": Renderer(city, w, h, 70.0, conditions=traj.conditions),
                "egl": GLRenderer(city, w, h, 70.0, conditions=traj.conditions)}
        for r in rend.values():  # JIT compile / shader compile + atlas upload outside the timings
            _time_stages(r, traj, int(frames[0]), None, None)
        sensor, note = _sensor(w, h)
        rng = np.random.default_rng(0)
        if sensor is not None:  # compile outside the timings
            sensor.capture(np.ones((h, w, 3), np.float32), 5000.0, 6.0, rng)
        times = {name: [] for name in rend}
        agree = []
        for i, k in enumerate(frames):
            order = list(rend) if i % 2 == 0 else list(rend)[::-1]
            sharp = {}
            for name in order:
                t, sharp[name] = _time_stages(rend[name], traj, int(k), sensor, rng)
                times[name].append(t)
            agree.append(float(np.mean(sharp["numba"]["code"] == sharp["egl"]["code"])))
        entry = {"sensor_note": note, "code_agreement_min": round(min(agree), 5)}
        for name, v in times.items():
            v = np.array(v)  # (frames, stages)
            cum = np.cumsum(v, axis=1)
            entry[name] = {
                "stage_median_ms": {s: round(1e3 * float(np.median(v[:, j])), 2) for j, s in enumerate(STAGES[:v.shape[1]])},
                "cumulative_median_ms": {lab: round(1e3 * float(np.median(cum[:, n - 1])), 2)
                                         for lab, n in CUMULATIVE if n <= v.shape[1]},
            }
            entry[name]["frames_per_s"] = {lab: round(1e3 / ms, 2) for lab, ms in entry[name]["cumulative_median_ms"].items()}
        entry["ratio_egl_over_numba"] = {lab: round(entry["egl"]["cumulative_median_ms"][lab]
                                                    / entry["numba"]["cumulative_median_ms"][lab], 3)
                                         for lab in entry["egl"]["cumulative_median_ms"]}
        result["sizes"][f"{w}x{h}"] = entry
        print(f"\n{w}x{h}, city {args.city}, {len(frames)} frames alternating, numba {numba.get_num_threads()} threads, "
              f"LP_NUM_THREADS={os.environ.get('LP_NUM_THREADS', 'default')}, load avg {os.getloadavg()[0]:.1f}"
              + (f"; sensor: {note}" if note else ""))
        print(f"{'per camera-frame (median)':26s} {'numba ms':>9s} {'egl ms':>9s} {'egl/numba':>9s} "
              f"{'numba f/s':>9s} {'egl f/s':>9s}")
        for lab in entry["egl"]["cumulative_median_ms"]:
            a, b = entry["numba"]["cumulative_median_ms"][lab], entry["egl"]["cumulative_median_ms"][lab]
            print(f"{lab:26s} {a:9.1f} {b:9.1f} {entry['ratio_egl_over_numba'][lab]:9.2f} "
                  f"{entry['numba']['frames_per_s'][lab]:9.1f} {entry['egl']['frames_per_s'][lab]:9.1f}")
        print("stage medians ms: " + "; ".join(f"{n} " + ", ".join(f"{s} {v}" for s, v in entry[n]["stage_median_ms"].items())
                                          for n in rend))
        print(f"code maps agree on >= {100 * entry['code_agreement_min']:.2f} % of pixels on every frame")
    result["max_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0, 1)
    result["load_average_1min_end"] = os.getloadavg()[0]
    print(f"\nmax RSS {result['max_rss_mb']} MB (both backends in one process; llvmpipe's buffers are host memory)")
    out = ROOT / "benchmarks" / "results" / "simulator_speed_backends.json"
    write_json(result, out)
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--threads", type=int, default=0, help="numba threads (0 = numba default)")
    ap.add_argument("--city", default="train")
    ap.add_argument("--baseline", default=None, help="another version's src dir to time alongside (see docstring)")
    ap.add_argument("--backend", choices=("numba", "egl", "both"), default="numba")
    ap.add_argument("--sizes", default="640x480,320x240", help="--backend both: image sizes WxH, comma-separated")
    ap.add_argument("--lp-threads", type=int, default=0, help="LP_NUM_THREADS for llvmpipe (0 = its default)")
    args = ap.parse_args()
    if args.threads:
        numba.set_num_threads(args.threads)
    if args.lp_threads:
        os.environ["LP_NUM_THREADS"] = str(args.lp_threads)  # read by llvmpipe when the context is created
    if args.backend == "both":
        return compare_backends(args)
    if args.backend == "egl":
        from expoctl.world.gl_renderer import GLRenderer
        cls = GLRenderer
    else:
        cls = Renderer

    tracemalloc.start()
    t_setup = time.perf_counter()
    city = load_city(args.city)
    traj = city.traversal(0, None, fps=15.0, seed=0)
    renderer = cls(city, args.width, args.height, 70.0, conditions=traj.conditions)
    shared = cls(city, args.width, args.height, 70.0, conditions=traj.conditions, share_render=True)
    renderer.render_full(traj.poses[0])  # JIT compile / load cache outside the timings
    shared.render_exposure(traj, 0, 5000.0)
    setup_s = time.perf_counter() - t_setup
    sensor, sensor_note = _sensor(args.width, args.height)
    rng = np.random.default_rng(0)

    frames = np.linspace(1, len(traj.poses) - 2, args.frames).astype(int)
    rows = {k: [] for k in ("render_sharp", "render_blur_5ms", "render_blur_20ms", "sensor", "total_5ms",
                            "rig_pair_shared_5ms")}
    cpu = {"render_sharp": [], "sensor": []}
    for k in frames:
        t, c = time.perf_counter(), time.process_time()
        renderer.render(traj.poses[k])
        rows["render_sharp"].append(time.perf_counter() - t)
        cpu["render_sharp"].append(time.process_time() - c)
        for exp_us, key in ((5000.0, "render_blur_5ms"), (20000.0, "render_blur_20ms")):
            renderer._cache.clear()
            t = time.perf_counter()
            lum = renderer.render_exposure(traj, int(k), exp_us)
            rows[key].append(time.perf_counter() - t)
        lum5 = renderer.render_exposure(traj, int(k), 5000.0)  # cached sharp render: smear only
        if sensor is not None:
            t, c = time.perf_counter(), time.process_time()
            sensor.capture(lum5, 5000.0, 6.0, rng)
            rows["sensor"].append(time.perf_counter() - t)
            cpu["sensor"].append(time.process_time() - c)
            rows["total_5ms"].append(rows["render_blur_5ms"][-1] + rows["sensor"][-1])
        shared._cache.clear()
        t = time.perf_counter()  # both cameras of the rig from one render (share_render=True), per camera
        shared.render_exposure(traj, int(k), 5000.0)
        shared.render_exposure(traj, int(k), 5000.0, camera_offset_m=0.0392)
        rows["rig_pair_shared_5ms"].append((time.perf_counter() - t) / 2)
        del lum
    _, peak_py = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    maxrss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    # the baseline runs after the memory figures, which are the current code's alone
    baseline = None
    if args.baseline:
        old = _load_baseline(args.baseline)
        old_city = old.load_city(args.city)
        old_traj = old_city.traversal(0, None, fps=15.0, seed=0)
        old_r = old.Renderer(old_city, args.width, args.height, 70.0, conditions=old_traj.conditions)
        old_r.render_exposure(old_traj, 0, 5000.0)  # compile outside the timings
        times = {"old": [], "new": []}
        identical = True
        for i, k in enumerate(frames):  # alternate which goes first: neither always meets the other's cache state
            order = (("old", old_r, old_traj), ("new", renderer, traj))
            res = {name: _time_render(r, tr, k) for name, r, tr in (order if i % 2 == 0 else order[::-1])}
            identical &= bool(np.array_equal(res["old"][3], res["new"][3]))
            for name in times:
                times[name].append(res[name][:3])
        med = {name: 1e3 * np.median(np.array(v), axis=0) for name, v in times.items()}
        baseline = {"src": str(args.baseline), "sharp_images_identical": identical}
        for j, key in enumerate(("render_sharp", "render_sharp_cpu", "render_blur_5ms")):
            baseline[key] = {"old_ms": round(float(med["old"][j]), 2), "new_ms": round(float(med["new"][j]), 2),
                             "speedup": round(float(med["old"][j] / med["new"][j]), 2)}

    result = {
        "city": args.city, "backend": args.backend, "width": args.width, "height": args.height,
        "frames": int(len(frames)), "lp_num_threads": os.environ.get("LP_NUM_THREADS"),
        "numba_threads": numba.get_num_threads(), "cpu_count": os.cpu_count(),
        "load_average_1min": os.getloadavg()[0], "python": platform.python_version(),
        "setup_s": round(setup_s, 2), "sensor_note": sensor_note,
        "median_ms": {k: round(1e3 * float(np.median(v)), 2) for k, v in rows.items() if v},
        "frames_per_s": {k: round(1.0 / float(np.median(v)), 2) for k, v in rows.items() if v},
        "median_cpu_ms": {k: round(1e3 * float(np.median(v)), 2) for k, v in cpu.items() if v},
        "peak_python_alloc_mb": round(peak_py / 2**20, 1), "max_rss_mb": round(maxrss_mb, 1),
    }
    if baseline is not None:
        result["baseline"] = baseline
    print(f"simulator speed ({args.backend}), {args.width}x{args.height}, city {args.city}, {len(frames)} frames, "
          f"{result['numba_threads']} numba threads, load avg {result['load_average_1min']:.1f}")
    print(f"{'stage (per camera-frame)':28s} {'median ms':>10s} {'frames/s':>9s}")
    for k in rows:
        if rows[k]:
            print(f"{k:28s} {result['median_ms'][k]:10.1f} {result['frames_per_s'][k]:9.2f}")
    for k, v in result["median_cpu_ms"].items():
        print(f"{'cpu time ' + k:28s} {v:10.1f}   (process CPU time, all threads: cost without contention)")
    if sensor_note:
        print(f"sensor: {sensor_note}")
    if baseline is not None:
        print(f"baseline {baseline['src']} on the same frames, alternating (sharp images identical: "
              f"{baseline['sharp_images_identical']}):")
        for key in ("render_sharp", "render_sharp_cpu", "render_blur_5ms"):
            b = baseline[key]
            print(f"  {key:26s} old {b['old_ms']:8.1f} ms  new {b['new_ms']:8.1f} ms  speed-up {b['speedup']:.2f}x")
    print(f"peak python allocations {result['peak_python_alloc_mb']} MB, max RSS {result['max_rss_mb']} MB")
    out = ROOT / "benchmarks" / "results" / ("simulator_speed_egl.json" if args.backend == "egl" else "simulator_speed.json")
    write_json(result, out)
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
