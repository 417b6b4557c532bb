"""Simulator speed: render (+ motion blur) (+ sensor, when expoctl.camera.sensor exists) frames/s per camera, and memory.

Usage: .venv/bin/python benchmarks/simulator_speed.py [--frames 12] [--width 640] [--height 480] [--threads 0] [--skip-stages]
                                                    [--portal-daylight exact|light_map]
                                                    [--baseline OLD_SRC [--baseline-label COMMIT]] [--out FILE]
                                                    [--backend numba|egl|both]
                                                    [--sizes 640x480,320x240] [--lp-threads N]
Prints a table of medians over frames and writes benchmarks/results/simulator_speed.json.
--backend egl: the same table for the OpenGL backend (gl_renderer.GLRenderer on headless EGL).
--backend both: time numba and egl alternating on the same frames, at each of --sizes, stage by stage (sharp render,
+ 5 ms fast blur, + glare, + sensor), with egl/numba ratios and frames/s per camera; writes
benchmarks/results/simulator_speed_backends.json (--backend egl writes simulator_speed_egl.json).
--lp-threads: LP_NUM_THREADS for Mesa llvmpipe (set before the GL context exists; default: llvmpipe's own).
--out FILE: where the stage table's JSON goes; --baseline-label: what OLD_SRC is (a commit), recorded in it.
--baseline OLD_SRC: also time another version of the code (a `src` directory, e.g. from
`git archive <commit> src | tar -x -C /tmp/old` → /tmp/old/src) on the same frames, alternating with the current code
frame by frame, and report both medians, their ratio and whether the images are identical (sharp render, 5 ms blur,
sensor image; plus the fast blur alone at 75 µs–5 ms): on a shared machine only ratios measured in one run compare.
The copy of OLD_SRC is kept in the temporary directory while OLD_SRC is unchanged, so its kernels compile once.
--skip-stages: only the --baseline comparison.
--identity-check (with --baseline): the default outputs of both versions bit for bit on poses of --identity-cities
(open road, in and at every portal; two traversals each): sharp render, fast blur 75 µs–30 ms for both cameras,
share_render, reference blur, sensor 8-bit and raw; exit 1 on any difference.
--light-map-check: portal_daylight light_map vs exact on --frames frames per tunnel of --identity-cities, against the
registered bounds of docs/simulator.md; writes benchmarks/results/simulator_speed_light_map.json.
--portal-daylight: world.render.portal_daylight of the current code's renderers.
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
sys.path.insert(0, str(ROOT / "benchmarks"))

import importlib  # noqa: E402
import inspect  # noqa: E402
import re  # noqa: E402
import shutil  # noqa: E402
import tempfile  # noqa: E402

from expoctl.io import write_json  # noqa: E402
import expoctl.world  # noqa: E402
from expoctl.world import Renderer, load_city  # noqa: E402
from bench_meta import run_metadata  # noqa: E402


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
    """The `expoctl` of another source tree, imported as package `expoctl_baseline` (a renamed copy), so both versions
    run in this process on the same frames. The copy lives in a directory named after the source path and is reused
    while the source is unchanged: numba's on-disk cache is keyed by file path and time stamp, so a fresh copy per run
    recompiled every kernel of the old code (minutes on a shared 2-core machine)."""
    import hashlib

    src_pkg = Path(src).resolve() / "expoctl"
    files = sorted(f for f in src_pkg.rglob("*.py"))
    stamp = hashlib.sha1("".join(f"{f}:{f.stat().st_mtime_ns}" for f in files).encode()).hexdigest()[:12]
    tmp = Path(tempfile.gettempdir()) / f"expoctl_baseline_{stamp}"
    pkg = tmp / "expoctl_baseline"
    if not (tmp / "complete").is_file():
        shutil.rmtree(tmp, ignore_errors=True)
        shutil.copytree(src_pkg, pkg, ignore=shutil.ignore_patterns("__pycache__"))
        for f in pkg.rglob("*.py"):
            text = re.sub(r"\bexpoctl\.", "expoctl_baseline.", f.read_text())
            f.write_text(text.replace("from expoctl import", "from expoctl_baseline import"))
        (tmp / "complete").write_text(str(src_pkg))
    sys.path.insert(0, str(tmp))
    return importlib.import_module("expoctl_baseline.world"), importlib.import_module("expoctl_baseline.camera.sensor")


def make_renderer_any(world_mod, city, width, height, hfov_deg, conditions, **options):
    """A numba Renderer of either API: `Renderer(city, RenderConfig, conditions)` (since issue 44) or the older
    `Renderer(city, width, height, hfov_deg, **options, conditions=...)` (a --baseline before it)."""
    cls = options.pop("cls", None) or world_mod.Renderer
    if "render" in inspect.signature(cls.__init__).parameters:
        cfg = world_mod.RenderConfig(width=width, height=height, hfov_deg=hfov_deg, **options)
        return cls(city, cfg, conditions=conditions)
    return cls(city, width, height, hfov_deg, conditions=conditions, **options)


def _baseline_sensor(sensor_mod, width, height):
    import yaml
    cfg = yaml.safe_load((ROOT / "conf" / "sensor" / "default.yaml").read_text())
    try:
        return sensor_mod.Sensor(sensor_mod.SensorConfig.from_dict(cfg), height, width, 0)
    except Exception as exc:  # an old sensor that does not read today's config: time the renders alone
        print(f"baseline sensor not available: {exc}")
        return None


# per camera-frame columns of the --baseline comparison: sharp render (wall, CPU), render + 5 ms fast blur (incl.
# glare, sensor capture of that, and the whole frame (blurred render + sensor); then, per SMEAR_EXPOSURES_US, the fast
# blur alone (its sharp render cached): most of a frame's smears in evaluate, where every controller and oracle
# candidate smears the frame's render at its own exposure, and the short ones barely move
SMEAR_EXPOSURES_US = (75.0, 300.0, 1000.0, 5000.0)
FRAME_COLUMNS = ("render_sharp", "render_sharp_cpu", "render_blur_5ms", "sensor", "frame_5ms",
                 *(f"smear_{e:g}us" for e in SMEAR_EXPOSURES_US))


def _time_frame(renderer, traj, sensor, k):
    """(seconds per FRAME_COLUMNS, outputs (sharp (luminance, depth), blurred (luminance,), sensor (image,) or None))
    for frame k; the sensor draws from a generator seeded with k, so two versions see the same noise."""
    t, c = time.perf_counter(), time.process_time()
    lum, depth = renderer.render(traj.poses[k])
    sharp, sharp_cpu = time.perf_counter() - t, time.process_time() - c
    renderer._cache.clear()
    t = time.perf_counter()
    blurred = renderer.render_exposure(traj, int(k), 5000.0)
    blur = time.perf_counter() - t
    img, cap = None, float("nan")
    if sensor is not None:
        t = time.perf_counter()
        img = sensor.capture(blurred, 5000.0, 6.0, np.random.default_rng(int(k)))
        cap = time.perf_counter() - t
    smears, smeared = [], []
    for exp_us in SMEAR_EXPOSURES_US:  # the sharp render at this exposure's mid-point, then the smear (+ glare) alone
        renderer.render_exposure(traj, int(k), exp_us)
        t = time.perf_counter()
        smeared.append(renderer.render_exposure(traj, int(k), exp_us))
        smears.append(time.perf_counter() - t)
    return ((sharp, sharp_cpu, blur, cap, blur + cap, *smears),
            ((lum, depth), (blurred, *smeared), None if img is None else (img,)))


def _max_rel(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-9)))


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
        rend = {"numba": make_renderer_any(expoctl.world, city, w, h, 70.0, traj.conditions),
                "egl": make_renderer_any(expoctl.world, city, w, h, 70.0, traj.conditions, cls=GLRenderer)}
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


def identity_check(args) -> int:
    """--identity-check: the current code's default outputs against --baseline's, bit for bit (np.array_equal), on
    poses that cover the scene types — open road, inside and at the portals of every tunnel (train: box tunnels;
    test: the curved arch tunnel and the underpass; stress: low sun / dark overcast), two traversals each (other sun,
    sky) — for the sharp render (luminance, depth, code, material), the fast blur at 75 µs … 30 ms for both cameras of
    the rig, share_render, the reference blur, and the sensor (8-bit capture and raw) of each blurred image."""
    old_world, old_sensor_mod = _load_baseline(args.baseline)
    w, h = args.width, args.height
    checks, failed = 0, []
    for name in args.identity_cities.split(","):
        for tr in (0, 1):
            new_city, old_city = load_city(name), old_world.load_city(name)
            traj = new_city.traversal(tr, None, fps=15.0, seed=0)
            old_traj = old_city.traversal(tr, None, fps=15.0, seed=0)
            pairs = [(make_renderer_any(mod, c, w, h, 70.0, t.conditions, **opt), t)
                     for mod, c, t in ((expoctl.world, new_city, traj), (old_world, old_city, old_traj))
                     for opt in ({}, {"share_render": True})]
            sensors = (_sensor(w, h)[0], _baseline_sensor(old_sensor_mod, w, h))
            ss = [float(s) for s in np.linspace(0.0, new_city.route.length_m - 1.0, 5)]
            for t in new_city.cfg["tunnels"]:
                a, length = float(t["start_m"]), float(t["length_m"])
                ss += [a - 3.0, a + 0.5, a + 0.5 * length, a + length - 2.0, a + length + 1.0]
            s_frames = np.asarray(traj.s_at(traj.timestamps_ns * 1e-9))
            length = new_city.route.length_m
            gap = lambda s: np.abs((s_frames - s + 0.5 * length) % length - 0.5 * length)  # noqa: E731
            frames = sorted({min(max(int(np.argmin(gap(s))), 1), len(traj.poses) - 2) for s in ss})
            for k in frames:
                new_r, new_sh, old_r, old_sh = (p[0] for p in pairs)
                a, b = new_r.render_full(traj.poses[k]), old_r.render_full(old_traj.poses[k])
                for key in ("luminance", "depth", "code", "material"):
                    checks += 1
                    if not np.array_equal(a[key], b[key], equal_nan=True):
                        failed.append((name, tr, k, "sharp", key))
                for exp_us in (75.0, 1000.0, 5000.0, 30000.0):
                    for cam in (0.0, 0.0392):
                        outs = []
                        for r, t in ((new_r, traj), (old_r, old_traj)):
                            r._cache.clear()
                            outs.append(r.render_exposure(t, k, exp_us, camera_offset_m=cam))
                        caps = [sen.capture(o, exp_us, 12.0, np.random.default_rng(k)) for sen, o in zip(sensors, outs)]
                        raws = [sen.capture_raw(o, exp_us, 12.0, np.random.default_rng(k)) for sen, o in zip(sensors, outs)]
                        for what, (x, y) in (("blur", outs), ("sensor", caps), ("raw", raws)):
                            checks += 1
                            if not np.array_equal(x, y):
                                failed.append((name, tr, k, what, exp_us, cam))
                    shared = [r.render_exposure(t, k, exp_us, camera_offset_m=0.0392)
                              for r, t in ((new_sh, traj), (old_sh, old_traj))]
                    checks += 1
                    if not np.array_equal(*shared):
                        failed.append((name, tr, k, "share_render", exp_us))
                if k == frames[len(frames) // 2]:
                    ref = [r.render_exposure(t, k, 5000.0, method="reference") for r, t in ((new_r, traj), (old_r, old_traj))]
                    checks += 1
                    if not np.array_equal(*ref):
                        failed.append((name, tr, k, "reference blur"))
            print(f"{name} traversal {tr}: {len(frames)} poses checked, {len(failed)} differences so far")
    print(f"identity check vs {args.baseline} at {w}x{h}: {checks} arrays compared, {len(failed)} differ"
          + ("".join(f"\n  {f}" for f in failed[:20])))
    return 1 if failed else 0


def light_map_check(args) -> int:
    """--light-map-check: world.render.portal_daylight light_map against exact (the current code, both), on frames of
    traversal 0 inside and at the portals of every tunnel of --identity-cities, at --width × --height: the registered
    bounds 2 and 3 of docs/simulator.md (per-pixel relative luminance error p99 / max of the sharp render; code and
    depth maps identical; ORB inliers between consecutive frames through the same sensor and noise, |ΔNFM| / NFM),
    and the sharp render's time both ways, alternating on the same frames."""
    from expoctl.features.orb import OrbFrontEnd
    from expoctl.features.pipeline import match_images, rgb_to_grey

    orb = OrbFrontEnd(yaml_conf("features").get("orb"))
    sensor = _sensor(args.width, args.height)[0]
    errs, same_maps, nfm, times = [], True, [], {"exact": [], "light_map": []}
    for name in args.identity_cities.split(","):
        city = load_city(name)
        traj = city.traversal(0, None, fps=15.0, seed=0)
        rend = {m: make_renderer_any(expoctl.world, city, args.width, args.height, 70.0, traj.conditions,
                                     portal_daylight=m) for m in times}
        s_frames = np.asarray(traj.s_at(traj.timestamps_ns * 1e-9))
        for ti, t in enumerate(city.cfg["tunnels"]):
            a, length = float(t["start_m"]), float(t["length_m"])
            inside = np.flatnonzero((s_frames > a - 5.0) & (s_frames < a + length + 5.0))
            inside = inside[inside < len(traj.poses) - 1]
            for n, k in enumerate(inside[np.linspace(0, len(inside) - 1, args.frames).astype(int)]):
                k = int(k)
                out, imgs = {}, {}
                for m in (("exact", "light_map") if n % 2 == 0 else ("light_map", "exact")):
                    t0 = time.perf_counter()
                    out[m] = [rend[m].render_full(traj.poses[k + d]) for d in (0, 1)]
                    times[m].append((time.perf_counter() - t0) / 2)
                ex, lm = out["exact"], out["light_map"]
                for d in (0, 1):
                    same_maps &= bool(np.array_equal(ex[d]["code"], lm[d]["code"])
                                      and np.array_equal(ex[d]["depth"], lm[d]["depth"]))
                    y_ex, y_lm = (o[d]["luminance"].astype(np.float64) for o in (ex, lm))
                    errs.append(np.abs(y_lm - y_ex).ravel() / np.maximum(np.abs(y_ex).ravel(), 1e-12))
                p95 = float(np.quantile(ex[0]["luminance"], 0.95))
                exp_us = float(np.clip(0.8 * sensor.saturation_luminance_cd_m2(1.0, 12.0) / max(p95, 1e-9), 75.0, 30000.0))
                for m in ("exact", "light_map"):
                    g = [rgb_to_grey(sensor.capture(o["luminance"], exp_us, 12.0, np.random.default_rng(k + d)))
                         for d, o in enumerate(out[m])]
                    imgs[m] = match_images(orb, g[0], g[1], seed=k).n_inliers
                nfm.append((name, ti, k, imgs["exact"], imgs["light_map"]))
            print(f"{name} tunnel {ti}: {len(inside)} frames in or within 5 m of it, {args.frames} checked", flush=True)
    e = np.concatenate(errs)
    d_nfm = np.array([abs(b - a) / max(a, 1) for *_, a, b in nfm])
    med = {m: 1e3 * float(np.median(v)) for m, v in times.items()}
    result = {"width": args.width, "height": args.height, "numba_threads": numba.get_num_threads(),
              "load_average_1min": os.getloadavg()[0], "cities": args.identity_cities, "pairs": len(nfm),
              "pixel_rel_error": {"p50": float(np.median(e)), "p99": float(np.quantile(e, 0.99)), "max": float(e.max())},
              "code_and_depth_identical": same_maps,
              "nfm": {"median_abs_rel_change": float(np.median(d_nfm)), "max_abs_rel_change": float(d_nfm.max()),
                      "pairs": [list(map(lambda v: v if isinstance(v, str) else int(v), row)) for row in nfm]},
              "sharp_render_ms": {"exact": round(med["exact"], 2), "light_map": round(med["light_map"], 2),
                                  "speedup": round(med["exact"] / med["light_map"], 2)},
              "bounds_hold": bool(np.quantile(e, 0.99) <= 1e-3 and e.max() <= 2e-3 and same_maps
                                  and np.median(d_nfm) <= 0.02)}
    print(f"light map vs exact, {len(nfm)} frame pairs at {args.width}x{args.height}: pixel relative error p50 "
          f"{result['pixel_rel_error']['p50']:.2e}, p99 {result['pixel_rel_error']['p99']:.2e}, max "
          f"{result['pixel_rel_error']['max']:.2e}; code and depth identical: {same_maps}; |dNFM|/NFM median "
          f"{result['nfm']['median_abs_rel_change']:.4f}, max {result['nfm']['max_abs_rel_change']:.4f}; sharp render "
          f"exact {med['exact']:.1f} ms, light map {med['light_map']:.1f} ms ({result['sharp_render_ms']['speedup']}x); "
          f"registered bounds hold: {result['bounds_hold']}")
    out = ROOT / "benchmarks" / "results" / "simulator_speed_light_map.json"
    write_json(result, out)
    print(f"wrote {out.relative_to(ROOT)}")
    return 0


def yaml_conf(group: str) -> dict:
    import yaml
    p = ROOT / "conf" / group / "default.yaml"
    return (yaml.safe_load(p.read_text()) or {}) if p.is_file() else {}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--threads", type=int, default=0, help="numba threads (0 = numba default)")
    ap.add_argument("--city", default="train")
    ap.add_argument("--baseline", default=None, help="another version's src dir to time alongside (see docstring)")
    ap.add_argument("--baseline-label", default=None,
                    help="what --baseline is (e.g. the commit it was archived from), recorded in the JSON")
    ap.add_argument("--out", default=None, help="the JSON file of the stage table (default: see docstring)")
    ap.add_argument("--backend", choices=("numba", "egl", "both"), default="numba")
    ap.add_argument("--sizes", default="640x480,320x240", help="--backend both: image sizes WxH, comma-separated")
    ap.add_argument("--lp-threads", type=int, default=0, help="LP_NUM_THREADS for llvmpipe (0 = its default)")
    ap.add_argument("--portal-daylight", choices=("exact", "light_map"), default="exact",
                    help="world.render.portal_daylight of the current code's renderers")
    ap.add_argument("--skip-stages", action="store_true", help="only the --baseline comparison (no stage rows)")
    ap.add_argument("--identity-check", action="store_true",
                    help="with --baseline: compare default outputs bit for bit on poses of --identity-cities (exit 1 "
                         "on any difference)")
    ap.add_argument("--identity-cities", default="train,test,stress")
    ap.add_argument("--light-map-check", action="store_true",
                    help="portal_daylight light_map vs exact on --frames frames per tunnel of --identity-cities")
    args = ap.parse_args()
    if args.threads:
        numba.set_num_threads(args.threads)
    if args.lp_threads:
        os.environ["LP_NUM_THREADS"] = str(args.lp_threads)  # read by llvmpipe when the context is created
    if args.backend == "both":
        return compare_backends(args)
    if args.identity_check:
        return identity_check(args)
    if args.light_map_check:
        return light_map_check(args)
    if args.backend == "egl":
        from expoctl.world.gl_renderer import GLRenderer
        cls = GLRenderer
    else:
        cls = Renderer

    tracemalloc.start()
    t_setup = time.perf_counter()
    city = load_city(args.city)
    traj = city.traversal(0, None, fps=15.0, seed=0)
    opts = {} if args.portal_daylight == "exact" else {"portal_daylight": args.portal_daylight}
    renderer = make_renderer_any(expoctl.world, city, args.width, args.height, 70.0, traj.conditions, cls=cls, **opts)
    shared = make_renderer_any(expoctl.world, city, args.width, args.height, 70.0, traj.conditions, cls=cls,
                               share_render=True, **opts)
    renderer.render_full(traj.poses[0])  # JIT compile / load cache outside the timings
    shared.render_exposure(traj, 0, 5000.0)
    setup_s = time.perf_counter() - t_setup
    sensor, sensor_note = _sensor(args.width, args.height)
    rng = np.random.default_rng(0)

    frames = np.linspace(1, len(traj.poses) - 2, args.frames).astype(int)
    rows = {k: [] for k in ("render_sharp", "render_blur_5ms", "render_blur_20ms", "sensor", "total_5ms",
                            "rig_pair_shared_5ms")}
    cpu = {"render_sharp": [], "sensor": []}
    for k in ([] if args.skip_stages else frames):
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
        old_world, old_sensor_mod = _load_baseline(args.baseline)
        old_city = old_world.load_city(args.city)
        old_traj = old_city.traversal(0, None, fps=15.0, seed=0)
        old_r = make_renderer_any(old_world, old_city, args.width, args.height, 70.0, old_traj.conditions)
        old_r.render_exposure(old_traj, 0, 5000.0)  # compile outside the timings
        old_sensor = _baseline_sensor(old_sensor_mod, args.width, args.height)
        versions = {"old": (old_r, old_traj, old_sensor), "new": (renderer, traj, sensor)}
        if old_sensor is not None and sensor is not None:
            old_sensor.capture(np.ones((args.height, args.width, 3), np.float32), 5000.0, 6.0, rng)
        times = {"old": [], "new": []}
        same = {"sharp": True, "blur_5ms": True, "sensor": True}
        worst = {"sharp": 0.0, "blur_5ms": 0.0}
        for i, k in enumerate(frames):  # alternate which goes first: neither always meets the other's cache state
            order = ("old", "new") if i % 2 == 0 else ("new", "old")
            res = {name: _time_frame(*versions[name], int(k)) for name in order}
            for j, key in enumerate(("sharp", "blur_5ms", "sensor")):
                if res["old"][1][j] is not None and res["new"][1][j] is not None:
                    same[key] &= all(np.array_equal(x, y) for x, y in zip(res["old"][1][j], res["new"][1][j]))
                    if key in worst:
                        worst[key] = max(worst[key], _max_rel(res["old"][1][j][0], res["new"][1][j][0]))
            for name in times:
                times[name].append(res[name][0])
        med = {name: 1e3 * np.median(np.array(v), axis=0) for name, v in times.items()}
        baseline = {"src": str(args.baseline), "label": args.baseline_label, "new_portal_daylight": args.portal_daylight,
                    "identical": same, "max_rel_luminance_error": worst}
        for j, key in enumerate(FRAME_COLUMNS):
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
    result["run"] = run_metadata()
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
        print(f"baseline {baseline['src']} on the same frames, alternating; new code portal_daylight "
              f"{args.portal_daylight}; identical: {baseline['identical']}; max relative luminance error "
              f"{baseline['max_rel_luminance_error']}")
        for key in FRAME_COLUMNS:
            b = baseline[key]
            print(f"  {key:26s} old {b['old_ms']:8.1f} ms  new {b['new_ms']:8.1f} ms  speed-up {b['speedup']:.2f}x")
    print(f"peak python allocations {result['peak_python_alloc_mb']} MB, max RSS {result['max_rss_mb']} MB")
    out = (Path(args.out).resolve() if args.out else
           ROOT / "benchmarks" / "results" / ("simulator_speed_egl.json" if args.backend == "egl" else "simulator_speed.json"))
    write_json(result, out)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
