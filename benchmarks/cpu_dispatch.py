"""Which CPU-dependent code paths change expoctl's bytes on this host? (issue 46: find them by measurement)

Runs one small deterministic workload per library in a fresh process under each switch that pins a library's
run-time CPU dispatch, and compares the output hashes with the unpinned run on the same host:
- render: the numba ray caster (sharp luminance and a 5 ms motion-blurred exposure) at three poses of the training
  city's route (open road, the first portal, the tunnel), 160x120;
- sensor: the EMVA sensor's 8-bit capture of the blurred exposures (numpy's normal draws and arithmetic);
- orb: OpenCV ORB features and inlier matches between two captures;
- torch: eight Adam steps of a small CNN (expoctl.net.model) on seeded random data, then the weights.
A hash that differs from the unpinned run's means that switch reaches code whose result depends on the CPU's ISA, so
it matters for bit-identity across hosts; an equal hash means it does not, on this workload and this host (a host
whose ISA is the switch's baseline already cannot show a difference). numba's kernels compile afresh for every
NUMBA_* setting (own cache directory), so the pinned runs take minutes.

    .venv/bin/python benchmarks/cpu_dispatch.py            # table + benchmarks/results/cpu_dispatch.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "cpu_dispatch.json"

#: the AVX-512 groups numpy's dispatcher knows; disabling them leaves numpy's AVX2 paths
NPY_AVX512 = "AVX512F AVX512CD AVX512_KNL AVX512_KNM AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL AVX512_SPR"
#: name -> environment; each runs in its own process (the switches are read at import time)
CONFIGS: dict[str, dict[str, str]] = {
    "unpinned": {},
    "unpinned, again": {},  # the workload's own repeatability
    "numba: NUMBA_CPU_NAME=haswell (AVX2)": {"NUMBA_CPU_NAME": "haswell"},
    "numba: NUMBA_CPU_NAME=generic": {"NUMBA_CPU_NAME": "generic"},
    "numpy: NPY_DISABLE_CPU_FEATURES=AVX-512": {"NPY_DISABLE_CPU_FEATURES": NPY_AVX512},
    "torch: ATEN_CPU_CAPABILITY=avx2": {"ATEN_CPU_CAPABILITY": "avx2"},
    "torch: ATEN_CPU_CAPABILITY=default": {"ATEN_CPU_CAPABILITY": "default"},
    "oneDNN: ONEDNN_MAX_CPU_ISA=AVX2": {"ONEDNN_MAX_CPU_ISA": "AVX2"},
    "opencv: OPENCV_CPU_DISABLE=AVX512_SKX": {"OPENCV_CPU_DISABLE": "AVX512_SKX,AVX512_COMMON,AVX512_ICL,AVX512_CLX,"
                                                                    "AVX512_CNL,AVX512_KNL,AVX512_KNM"},
    "threads: torch 2 threads": {"EXPOCTL_BENCH_TORCH_THREADS": "2"},
}


def _h(a) -> str:
    import numpy as np

    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()[:16]


def workload() -> dict[str, str]:
    """The hashes of one run (in the child process)."""
    import cv2
    import numpy as np
    import torch

    from expoctl.camera.sensor import Sensor, SensorConfig
    from expoctl.features.orb import OrbFrontEnd
    from expoctl.net.model import ExposureNet, ModelConfig
    from expoctl.world import load_city
    from expoctl.world.render_config import RenderConfig
    from expoctl.world.renderer import Renderer
    import yaml

    city = load_city("train")
    traj = city.traversal(0, None, fps=15.0, seed=0)
    render = RenderConfig(width=160, height=120)
    r = Renderer(city, render, traj.conditions)
    start = float(city.cfg["tunnels"][0]["start_m"])
    s_frames = np.asarray(traj.s_at(traj.timestamps_ns * 1e-9))
    frames = [max(1, int(np.argmin(np.abs(s_frames - s)))) for s in (250.0, start - 1.0, start + 20.0)]
    sensor = Sensor(SensorConfig.from_dict(yaml.safe_load((ROOT / "conf/sensor/default.yaml").read_text())),
                    render.height, render.width, 0)
    sharp, blurred, captures = [], [], []
    for k in frames:
        sharp.append(r.render_full(traj.poses[k])["luminance"])
        lum = r.render_exposure(traj, k, 5000.0)
        blurred.append(lum)
        captures.append(sensor.capture(lum, 5000.0, 12.0, np.random.default_rng(k)))
    grey = [cv2.cvtColor(c, cv2.COLOR_RGB2GRAY) for c in captures]
    orb = OrbFrontEnd({"working_size": None, "count_nfeatures": 500, "match_nfeatures": 300})
    a, b = orb.extract(grey[0]), orb.extract(grey[1])
    matches = orb.match(a, b, 0)

    torch.manual_seed(0)
    torch.set_num_threads(int(os.environ.get("EXPOCTL_BENCH_TORCH_THREADS", "1")))
    net = ExposureNet(ModelConfig(input_size=(64, 64), conv_widths=(8, 16, 16, 32), fc_widths=(32, 16, 8)))
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    g = torch.Generator().manual_seed(1)
    for _ in range(8):
        x = torch.rand((16, 15, 64, 64), generator=g)
        y = torch.rand((16, 2), generator=g)
        opt.zero_grad()
        loss = (net(x) - y).abs().mean()
        loss.backward()
        opt.step()
    weights = torch.cat([p.detach().flatten() for p in net.state_dict().values() if p.dtype.is_floating_point])
    return {"render_sharp": _h(np.stack(sharp)), "render_blur": _h(np.stack(blurred)),
            "sensor": _h(np.stack(captures)), "orb": f"{_h(a.descriptors)}{_h(a.points_xy)}{_h(b.descriptors)}/{matches}",
            "torch": _h(weights.numpy())}


def _child() -> int:
    t0 = time.perf_counter()
    out = workload()
    out["seconds"] = round(time.perf_counter() - t0, 1)
    print("RESULT " + json.dumps(out))
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--only", help="comma-separated config names to run (default: all)")
    args = ap.parse_args()
    if args.child:
        return _child()
    names = list(CONFIGS) if not args.only else [n for n in CONFIGS if n in args.only.split(",")]
    rows: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            env = {**os.environ, **CONFIGS[name], "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)])}
            if any(k.startswith("NUMBA_") for k in CONFIGS[name]):  # compile for the pinned CPU, not from the cache
                env["NUMBA_CACHE_DIR"] = str(Path(tmp) / name.split(":")[0].replace(" ", "_") / str(len(rows)))
            p = subprocess.run([sys.executable, __file__, "--child"], env=env, capture_output=True, text=True)
            line = next((ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")), None)
            rows[name] = json.loads(line[7:]) if line else {"error": (p.stderr or p.stdout)[-500:]}
            print(f"{name:45s} {rows[name].get('seconds', 'error')}", flush=True)
    base = rows.get("unpinned", {})
    keys = ("render_sharp", "render_blur", "sensor", "orb", "torch")
    print(f"\n{'config':45s} " + " ".join(f"{k:>12s}" for k in keys))
    for name, r in rows.items():
        cells = ["error" if "error" in r else ("same" if r.get(k) == base.get(k) else "DIFFERS") for k in keys]
        print(f"{name:45s} " + " ".join(f"{c:>12s}" for c in cells))
    flags = set(open("/proc/cpuinfo").read().split()) if Path("/proc/cpuinfo").is_file() else set()
    meta = {"host_cpu": platform.processor() or platform.machine(),
            "avx512f": "avx512f" in flags, "avx2": "avx2" in flags, "python": platform.python_version()}
    try:
        import cv2
        import numba
        import numpy
        import torch
        meta.update(numpy=numpy.__version__, numba=numba.__version__, torch=torch.__version__, opencv=cv2.__version__)
    except ImportError:
        pass
    from expoctl.io import write_json

    write_json({"meta": meta, "configs": {n: {"env": CONFIGS[n], **rows[n]} for n in rows}}, RESULTS)
    print(f"wrote {RESULTS.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
