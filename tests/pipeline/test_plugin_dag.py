"""A controller and a front end from a package outside the repository, through the whole fixture-scale DAG.

The package is written here with its own pyproject.toml and entry points, installed by pip into a directory of
its own (`pip install --target`, the test's environment stays as it was) and put on the DVC run's PYTHONPATH. Then:
it is scored beside the built-ins in every report, and once it is gone again, compose names what is missing.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pandas as pd
import pytest

PYPROJECT = """
[build-system]
requires = ["setuptools"]
build-backend = "setuptools.build_meta"

[project]
name = "expoctl-demo-plugins"
version = "0.1.0"

[project.entry-points."expoctl.controllers"]
halfway = "expoctl_demo.halfway"

[project.entry-points."expoctl.frontends"]
corners = "expoctl_demo.corners"
"""

HALFWAY = '''
"""Closes half of the gap to mid grey in exposure product per frame, exposure first (a test plugin)."""
import math
from dataclasses import dataclass

import numpy as np

from expoctl.controllers import Controller, Settings, register_controller, split_exposure_first


@dataclass(frozen=True)
class HalfwayConfig:
    target_mean: float = 110.0  # 8-bit grey it steers to
    gain: float = 0.5           # share of the log error corrected per frame


@register_controller("halfway", config=HalfwayConfig, label="Halfway (plugin)", colour="#17becf")
class Halfway(Controller):
    def __init__(self, config):
        self.config = config

    def reset(self, initial):
        pass

    def update(self, image, applied):
        mean = max(float(np.mean(image)), 1.0)
        ln_p = math.log(applied.exposure_us) + applied.gain_db / (20 / math.log(10))
        return split_exposure_first(ln_p + self.config.gain * math.log(self.config.target_mean / mean))
'''

CORNERS = '''
"""Shi-Tomasi corners tracked by pyramidal Lucas-Kanade, verified by a RANSAC fundamental matrix (a test plugin)."""
from dataclasses import dataclass

import cv2
import numpy as np

from expoctl.features import register_frontend


@dataclass(frozen=True)
class CornersConfig:
    max_corners: int = 300
    quality: float = 0.01
    min_distance_px: float = 5.0
    ransac_threshold_px: float = 1.0


@register_frontend("corners", config=CornersConfig, label="GFTT+LK")
class Corners:
    def __init__(self, config):
        self.config = config

    def extract(self, grey):
        pts = cv2.goodFeaturesToTrack(grey, self.config.max_corners, self.config.quality, self.config.min_distance_px)
        return grey, (np.zeros((0, 1, 2), np.float32) if pts is None else pts)

    def n_features(self, extracted):
        return int(len(extracted[1]))

    def match(self, prev, cur, seed):
        if len(prev[1]) < 8:
            return 0, 0
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(prev[0], cur[0], prev[1], None)
        ok = status.ravel() == 1
        if ok.sum() < 8:
            return int(ok.sum()), 0
        cv2.setRNGSeed(int(seed))
        _, mask = cv2.findFundamentalMat(prev[1][ok], nxt[ok], cv2.FM_RANSAC, self.config.ransac_threshold_px, 0.99)
        return int(ok.sum()), 0 if mask is None else int(mask.sum())
'''


def _install(tmp_path):
    """Write the package and pip-install it into its own directory; returns that directory."""
    src = tmp_path / "demo-plugins"
    (src / "expoctl_demo").mkdir(parents=True)
    (src / "pyproject.toml").write_text(textwrap.dedent(PYPROJECT))
    (src / "expoctl_demo" / "__init__.py").write_text("")
    (src / "expoctl_demo" / "halfway.py").write_text(HALFWAY)
    (src / "expoctl_demo" / "corners.py").write_text(CORNERS)
    site = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation", "--target",
                    str(site), str(src)], check=True, capture_output=True, text=True)
    assert list(site.glob("expoctl_demo_plugins-0.1.0.dist-info/entry_points.txt"))
    return site


@pytest.mark.slow
def test_an_outside_controller_and_front_end_run_through_the_dag(project_copy, tmp_path):
    p = project_copy
    site = _install(tmp_path)
    base_path = p.env["PYTHONPATH"]
    p.env["PYTHONPATH"] = os.pathsep.join([base_path, str(site)])
    # labels count the outside front end too: their objective sums ORB's and its counts, each relative to its best
    p.set_overrides(["scale=fixture", "iteration2.enabled=false", "labels.frontend=orb+corners"])
    p.dvc("repro")

    features = pd.read_parquet(p.root / "data" / "features.parquet")
    matches = pd.read_parquet(p.root / "data" / "matches.parquet")
    assert set(features.frontend) == set(matches.frontend) == {"orb", "viso", "corners"}
    assert matches[matches.frontend == "corners"].n_inliers.max() > 0  # it matched something
    labels_report = json.loads((p.root / "reports" / "labels.json").read_text())
    assert "orb+corners" in json.dumps(labels_report)
    metrics = json.loads((p.root / "reports" / "metrics.json").read_text())
    for split in ("validation", "test"):
        assert set(metrics[split]) == {"agae", "shin", "shim", "mean_intensity", "fixed", "learned", "oracle",
                                       "halfway"}
        for entry in metrics[split].values():
            assert set(entry["dynamic"]) == {"orb", "viso", "corners", "orb_sumlog", "viso_sumlog", "corners_sumlog"}
    results = (p.root / "reports" / "results.md").read_text()
    assert "| Halfway (plugin) |" in results and "Median NFM GFTT+LK" in results
    assert (p.root / "reports" / "figures" / "fig7_tunnel_timeline.png").is_file()
    assert p.stage_runs(children=True) == {"evaluate": 8 * 2}  # its own MLflow child run per city, beside the others

    # Uninstalled: the next repro stops at compose, naming what the config asks for and nobody registers
    p.env["PYTHONPATH"] = base_path
    gone = p.dvc("repro", check=False)
    assert gone.returncode != 0
    out = gone.stdout + gone.stderr
    assert "config key 'labels.frontend'" in out and "'orb+corners'" in out, out[-3000:]
