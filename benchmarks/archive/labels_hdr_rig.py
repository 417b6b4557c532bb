"""Label statistics on a small image-based dual-camera rig: do our labels behave like the authors' (quality check)?

Until the full simulator feeds the pipeline, this drives the real pieces that matter for labelling — the AG+AE
reference controller (expoctl.controllers.agae), the paper's perturbation of camera 2 (expoctl.sim.protocol), the
closed loop with the t → t+1 latency (expoctl.sim.closed_loop) and the ORB front end (expoctl.features) — over a
panning crop of real HDR radiance maps (../shared/data/hdri), with a global light drop of 6 EV and back (a crude
tunnel: entry over 10 frames, exit over 5). The sensor is a plain linear model written here (shot and read noise,
full well, gain, 8-bit sRGB); no motion blur, no parallax between the two cameras. Then labels + label report.

    .venv/bin/python benchmarks/archive/labels_hdr_rig.py [--frames 140] [--scenes peppermint_powerplant_1k ...]

Prints the report; writes benchmarks/archive/results/labels_hdr_rig.json (stats) and labels_hdr_rig.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from expoctl.controllers.agae import AgAeController
from expoctl.controllers.base import Settings
from expoctl.features.pipeline import make_frontend, pair_seed, rgb_to_grey
from expoctl.labels.report import compute_label_stats, render_markdown
from expoctl.labels.targets import LabelConfig, compute_labels
from expoctl.sim.closed_loop import FunctionScene, run_closed_loop
from expoctl.sim.protocol import PerturbationConfig

HDRI = Path(__file__).resolve().parents[3] / "shared" / "data" / "hdri"
SCENES = ("peppermint_powerplant_1k", "modern_buildings_2_1k", "autoshop_01_1k")
W, H, PAN_PX = 256, 192, 3  # crop size and pan speed per frame


class LinearSensor:
    """electrons = L·t·k (k: mean scene luminance fills 20 % of the well at 5 ms), Poisson shot noise, 4 e⁻ read
    noise, gain 10^(g/20), clip at full scale, sRGB encode to 8 bits."""

    def __init__(self, k_e_per_cd_us: float, full_well_e: float = 10000.0, read_noise_e: float = 4.0):
        self.k, self.full_well, self.read = k_e_per_cd_us, full_well_e, read_noise_e

    def capture(self, luminance, exposure_us, gain_db, rng):
        electrons = rng.poisson(np.maximum(luminance * exposure_us * self.k, 0.0)).astype(np.float64)
        electrons += rng.normal(0.0, self.read, electrons.shape)
        linear = np.clip(electrons * 10.0 ** (gain_db / 20.0) / self.full_well, 0.0, 1.0)
        srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)
        return np.round(srgb * 255.0).astype(np.uint8)


def light_level(t: int, n: int) -> tuple[float, str]:
    """Global illumination factor and section kind: bright, 10-frame entry down 6 EV, tunnel, 5-frame exit."""
    a, b, c, d = int(0.3 * n), int(0.3 * n) + 10, int(0.65 * n), int(0.65 * n) + 5
    if t < a or t >= d:
        return 1.0, "static" if t < a - 5 or t >= d + 5 else "dynamic"
    if t < b:
        return 2.0 ** (-6.0 * (t - a) / (b - a)), "dynamic"
    if t < c:
        return 2.0 ** -6.0, "static" if a + 15 <= t < c - 5 else "dynamic"
    return 2.0 ** (-6.0 * (1 - (t - c) / (d - c))), "dynamic"


def drive(scene_name: str, n_frames: int, seed: int):
    hdr = cv2.imread(str(HDRI / f"{scene_name}.hdr"), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR)[..., ::-1]
    band = np.ascontiguousarray(hdr[160:160 + H].astype(np.float32))  # a horizontal band around the horizon
    lum = 0.2126 * band[..., 0] + 0.7152 * band[..., 1] + 0.0722 * band[..., 2]
    band *= 100.0 / float(np.mean(lum))  # mean 100 cd/m² in the bright part

    def luminance(t, exposure_us, camera):
        x0 = (t * PAN_PX) % (band.shape[1] - W)
        return band[:, x0:x0 + W] * light_level(t, n_frames)[0]

    sensor_k = 0.2 * 10000.0 / (100.0 * 5000.0)
    sensors = [LinearSensor(sensor_k), LinearSensor(sensor_k)]
    rig = run_closed_loop(FunctionScene(luminance, fps=15.0), sensors, AgAeController(), Settings(0.0, 5000.0),
                          range(0, n_frames), seed, perturbation=PerturbationConfig(), warmup_frames=30)
    orb = make_frontend("orb")
    frames, features, matches, prev = [], [], [], None
    for rf in rig:
        cur = {}
        for cf in rf.cameras:
            frames.append(dict(sequence=scene_name, frame_id=rf.frame_index, camera=cf.camera,
                               gain_db=cf.settings.gain_db, exposure_us=cf.settings.exposure_us, split="train",
                               section=light_level(rf.frame_index, n_frames)[1]))
            cur[cf.camera] = orb.extract(rgb_to_grey(cf.image))
            features.append(dict(sequence=scene_name, frame_id=rf.frame_index, camera=cf.camera, frontend="orb",
                                 n_features=orb.n_features(cur[cf.camera])))
        if prev is not None:
            for i in (1, 2):
                for j in (1, 2):
                    s = pair_seed(seed, scene_name, rf.frame_index - 1, i, j, "orb")
                    n_m, n_in = orb.match(prev[i], cur[j], s)
                    matches.append(dict(sequence=scene_name, frame_id=rf.frame_index - 1, cam_from=i, cam_to=j,
                                        frontend="orb", n_matches=n_m, n_inliers=n_in))
        prev = cur
    return pd.DataFrame(frames), pd.DataFrame(features), pd.DataFrame(matches)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=140)
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    if not HDRI.is_dir():
        print(f"skipped: {HDRI} is absent", file=sys.stderr)
        return 0
    t0 = time.perf_counter()
    tables = [drive(s, args.frames, args.seed + k) for k, s in enumerate(args.scenes)]
    frames, features, matches = (pd.concat(x, ignore_index=True) for x in zip(*tables))
    t_rig = time.perf_counter() - t0
    cfg = LabelConfig()
    labels = compute_labels(frames, features, matches, cfg)
    stats = compute_label_stats(labels, frames, vars(cfg))
    stats["rig_seconds"] = t_rig
    stats["median_orb_features"] = {str(c): float(features[features.camera == c].n_features.median()) for c in (1, 2)}
    stats["median_orb_inliers"] = {f"{i}->{j}": float(matches[(matches.cam_from == i) & (matches.cam_to == j)]
                                                        .n_inliers.median()) for i in (1, 2) for j in (1, 2)}
    md = render_markdown(stats)
    md += (f"\nMedian ORB features per image: {stats['median_orb_features']}; median inliers per pairing: "
           f"{stats['median_orb_inliers']}. Rig + ORB: {t_rig:.1f} s for {len(frames)} images.\n")
    print(md)
    out = Path(__file__).resolve().parent / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "labels_hdr_rig.json").write_text(json.dumps(stats, indent=2, default=float) + "\n")
    (out / "labels_hdr_rig.md").write_text(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
