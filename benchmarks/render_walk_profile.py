"""Where a 640×480 render walks (issue 47 profile): per frame, the segment steps of primary rays (and of those that end
in sky) and of shadow rays, on open-road and tunnel-interior frames of train traversal 0, one thread. Runs a copy of
raycast.trace with a step counter (its source, one counter line added), so it measures the code in the tree.
Usage: PYTHONPATH=src .venv/bin/python benchmarks/render_walk_profile.py  (CITY=test for the test city)"""
import inspect, math, os, sys, time
import numba
numba.set_num_threads(1)
import numpy as np
from numba import njit
from expoctl.world import raycast as rc, route as rt, Renderer, load_city, RenderConfig

src = inspect.getsource(rc.trace.py_func)
src = src.replace("def trace(seg, i0, inside0, ox, oy, oz, dx, dy, dz, tmax, ztop, cull, use_o, use_d, any_hit):",
                  "def trace_count(seg, i0, inside0, ox, oy, oz, dx, dy, dz, tmax, ztop, cull, use_o, use_d, any_hit, cnt):")
src = src.replace("    for _ in range(4096):\n", "    for _ in range(4096):\n        cnt[0] += 1\n")
src = src.replace("            # CULL_MARGIN_M, is above its top — the cull test's own rejection, reached without computing it)\n            pass\n",
                  "            # CULL_MARGIN_M, is above its top — the cull test's own rejection, reached without computing it)\n            cnt[1] += 1\n")
assert "cnt[1] += 1" in src, "trace's light step not found"
src = src.replace("@njit(cache=True)\n", "")
ns = dict(rc.__dict__)
exec(src, ns)
trace_count = njit(ns["trace_count"])

@njit
def frame(seg, lp, cam, rot, fx, fy, cx, cy, i0, inside, h, w, steps, codes, ssteps):
    segf = rc.with_frame_terms(seg, cam[0], cam[1], cam[2], lp[0], lp[1], lp[2])
    cnt = np.zeros(2, np.int64)
    light = 0
    for yy in range(h):
        for xx in range(w):
            cxr = (xx + 0.5 - cx) / fx
            cyr = (yy + 0.5 - cy) / fy
            nrm = 1.0 / math.sqrt(cxr * cxr + cyr * cyr + 1.0)
            dx = (rot[0, 0] * cxr + rot[0, 1] * cyr + rot[0, 2]) * nrm
            dy = (rot[1, 0] * cxr + rot[1, 1] * cyr + rot[1, 2]) * nrm
            dz = (rot[2, 0] * cxr + rot[2, 1] * cyr + rot[2, 2]) * nrm
            cnt[0] = 0
            cnt[1] = 0
            r = trace_count(segf, i0, inside, cam[0], cam[1], cam[2], dx, dy, dz, lp[rc.LP_TMAX], lp[rc.LP_ZTOP], True, True, False, False, cnt)
            steps[yy, xx] = cnt[0]
            light += cnt[1]
            codes[yy, xx] = r[1]
            t = r[0]
            if r[1] != rc.SKY and r[1] != rc.FAR:
                j = r[2]
                nu, nv, nw = r[8], r[9], r[10]
                nx = nu * seg[j, rt.F] + nv * seg[j, rt.R] + nw * seg[j, rt.U]
                ny = nu * seg[j, rt.F + 1] + nv * seg[j, rt.R + 1] + nw * seg[j, rt.U + 1]
                nz = nu * seg[j, rt.F + 2] + nv * seg[j, rt.R + 2] + nw * seg[j, rt.U + 2]
                if lp[rc.LP_E_SUN] > 0 and nx * lp[0] + ny * lp[1] + nz * lp[2] > 0 and lp[2] > 0:
                    cnt[0] = 0
                    px, py, pz = cam[0] + t * dx + 0.02 * nx, cam[1] + t * dy + 0.02 * ny, cam[2] + t * dz + 0.02 * nz
                    trace_count(segf, r[3], r[4], px, py, pz, lp[0], lp[1], lp[2], lp[rc.LP_TMAX], lp[rc.LP_ZTOP], True, False, True, True, cnt)
                    ssteps[yy, xx] = cnt[0]
    return light

city = load_city(os.environ.get("CITY", "train"))
traj = city.traversal(0, None, fps=15.0, seed=0)
r = Renderer(city, RenderConfig(width=640, height=480, hfov_deg=70.0), traj.conditions)
s = np.asarray(traj.s_at(traj.timestamps_ns * 1e-9))
tun = [(float(t["start_m"]), float(t["length_m"])) for t in city.cfg["tunnels"]]
def region(si):
    for a, L in tun:
        if a + 10 < si < a + L - 10: return "tunnel"
        if a - 40 < si < a + L + 40: return "portal"
    return "open"
reg = np.array([region(v) for v in s])
K = r.K
for name in ("open", "tunnel"):
    idx = np.flatnonzero(reg == name)
    fr = idx[np.linspace(0, len(idx) - 1, 6).astype(int)]
    agg = []
    for k in fr:
        pose = traj.poses[int(k)]
        i0, inside = r.locate(pose[:3, 3])
        steps = np.zeros((480, 640), np.int64); codes = np.zeros((480, 640), np.int64); ss = np.zeros((480, 640), np.int64)
        light = frame(r.seg, r.lp, np.ascontiguousarray(pose[:3, 3]), np.ascontiguousarray(pose[:3, :3]), K[0, 0], K[1, 1], K[0, 2], K[1, 2], i0, inside, 480, 640, steps, codes, ss)
        sky = codes == rc.SKY
        agg.append((steps.sum(), steps[sky].sum(), sky.mean(), ss.sum(), (ss > 0).mean(), np.percentile(steps, 99), np.percentile(ss[ss > 0], 99) if (ss > 0).any() else 0, light))
    a = np.array(agg, float)
    print(name, "per frame: primary steps %.0f (sky rays' %.0f), sky share %.2f, shadow steps %.0f on %.2f of pixels; p99 steps primary %.0f shadow %.0f; primary light steps %.0f" % tuple(np.median(a, axis=0)), flush=True)
