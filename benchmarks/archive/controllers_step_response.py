"""Step response and speed of the baseline controllers on a toy linear camera (not a timed test).

Scene: blurred log-normal texture (±1 EV spread), 320×240 grey; camera: radiance × t·gain → clip → sRGB 8-bit with
mild shot-like noise. Each controller first runs 80 frames on the dark scene (ideal product 30 ms at +20 dB), then
the radiance steps by ±10 EV (tunnel exit / entry) for 200 frames. Reported per controller and direction:
settle = frames after the step until the exposure product stays within 1/3 EV of its final value (mean of the last
20 frames); max_step_ev = largest frame-to-frame change of the product; median_change_pct = median |ΔP|/P per frame
over the 200 frames. Speed: median ms per update() at 640×480 over 30 calls.
Second table: the same ±10 EV steps through the project's EMVA-1288 sensor (expoctl.camera.sensor, defaults, f/2):
textured luminance with mean 5 cd/m² (tunnel interior) ↔ 5120 cd/m² (daylight).
Usage: .venv/bin/python benchmarks/archive/controllers_step_response.py
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import cv2
import numpy as np

from expoctl.controllers.base import Settings
from expoctl.camera.response import linear_to_8bit
from expoctl.controllers.registry import make_controller

NAMES = ["agae", "mean_intensity", "shim", "shin"]
P_REF = 1000.0
P_DARK = 30000.0 * 10.0  # 30 ms at +20 dB


def scene(shape=(240, 320), seed=0):
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(np.exp(rng.normal(0, 0.6, shape)), (0, 0), 1.0)
    return tex * 0.18 * P_REF / (P_DARK * tex.mean())


def capture(rad, s, rng):
    lin = rad * s.exposure_us * 10 ** (s.gain_db / 20) / P_REF
    lin = lin + rng.normal(0, 1, lin.shape) * np.sqrt(np.maximum(lin, 0) / 2000 + (1e-3 * 10 ** (s.gain_db / 20)) ** 2)
    return np.repeat(linear_to_8bit(lin)[..., None], 3, axis=2)


def ev(s):
    return math.log2(s.exposure_us) + s.gain_db / (20 * math.log10(2))


def emva_camera():
    from expoctl.camera.sensor import Sensor, SensorConfig

    sensor = Sensor(SensorConfig(), 240, 320, seed=0)
    tex = scene()
    lum = np.repeat((tex / tex.mean() * 5.0)[..., None], 3, axis=2).astype(np.float32)  # 5 cd/m² mean
    return lambda rad_scale, s, rng: sensor.capture(lum * rad_scale, s.exposure_us, s.gain_db, rng)


def step_response(name, ev_step, n_before=80, n_after=200, camera=None):
    rng = np.random.default_rng(1)
    if camera is None:
        dark = scene()
        cam = lambda k, s, r: capture(dark * k, s, r)  # noqa: E731
    else:
        cam = camera
    first, second = (1.0, 2.0**ev_step) if ev_step > 0 else (2.0**-ev_step, 1.0)
    c = make_controller(name, {})
    s = Settings(0.0, 5000.0)
    c.reset(s)
    evs = []
    for i in range(n_before + n_after):
        evs.append(ev(s))
        s = c.update(cam(first if i < n_before else second, s, rng), s)
    evs = np.array(evs)
    after = evs[n_before:]
    final = after[-20:].mean()
    off = np.nonzero(np.abs(after - final) > 1 / 3)[0]
    settle = int(off.max() + 1) if off.size else 0
    d = np.diff(evs[n_before - 1 :])
    return {
        "settle_frames": settle if settle < n_after - 20 else None,  # None: not settled within the run
        "max_step_ev": float(np.abs(d).max()),
        "median_change_pct": float(np.median(np.abs(2**d - 1)) * 100),
    }


def speed(name, n=30):
    rng = np.random.default_rng(0)
    img = capture(cv2.resize(scene(), (640, 480)) * 30, Settings(0.0, 5000.0), rng)
    c = make_controller(name, {})
    s = Settings(0.0, 5000.0)
    c.reset(s)
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        s = c.update(img, s)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def main():
    results = {}
    print(f"{'controller':15s} {'dir':>5s} {'settle':>7s} {'max EV/fr':>9s} {'med %/fr':>9s} {'ms/update':>10s}")
    for name in NAMES:
        ms = speed(name)
        results[name] = {"ms_per_update_640x480": ms}
        for label, st in (("exit", 10.0), ("entry", -10.0)):
            r = step_response(name, st)
            results[name][label] = r
            settle = "—" if r["settle_frames"] is None else str(r["settle_frames"])
            print(f"{name:15s} {label:>5s} {settle:>7s} {r['max_step_ev']:9.3f} {r['median_change_pct']:9.2f} {ms:10.1f}")
    print("\nwith the EMVA-1288 sensor (5 ↔ 5120 cd/m², f/2)")
    camera = emva_camera()
    for name in NAMES:
        for label, st in (("exit", 10.0), ("entry", -10.0)):
            r = step_response(name, st, camera=camera)
            results[name][label + "_emva_sensor"] = r
            settle = "—" if r["settle_frames"] is None else str(r["settle_frames"])
            print(f"{name:15s} {label:>5s} {settle:>7s} {r['max_step_ev']:9.3f} {r['median_change_pct']:9.2f}")
    out = Path(__file__).parent / "results" / "controllers_step_response.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
