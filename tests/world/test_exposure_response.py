"""Behaviour checks of the closed-loop simulator (simulator spec, Validation): inliers vs exposure at a fixed pose form
an inverted U that moves with scene luminance; high gain at equal brightness raises false detections.

Train city from conf/, traversal 0 (sun), 160×120, ORB as the features stage configures it; expoctl.sim.exposure_sweep
does the sweeps (benchmarks/archive/exposure_response.py reports the same at 320×240 with the libviso2-style front end too).
"""

from pathlib import Path

import numpy as np
import pytest
import yaml

from expoctl.features.pipeline import make_frontend
from expoctl.sim import exposure_sweep as xs
from expoctl.camera.sensor import SensorConfig
from expoctl.sim.closed_loop import RenderConfig, RigConfig, RouteScene, make_sensors
from expoctl.world import load_city

ROOT = Path(__file__).resolve().parents[2]
TOL_EV = 1.5  # peak positions are read off a 0.5 EV grid from one noisy pair: allow three grid steps


def _conf(name):
    return yaml.safe_load((ROOT / "conf" / name / "default.yaml").read_text())


@pytest.fixture(scope="module")
def world():
    w, rig = _conf("world"), RigConfig.from_dict(_conf("rig"))
    render = RenderConfig.from_world(w).with_size(160, 120)
    city = load_city(w["cities"]["train"], str(ROOT / w["city_dir"]))
    traj = city.traversal(0, None, rig.fps, 0)
    assert not traj.conditions.overcast  # the open-road pose is in sunlight
    scene = RouteScene(city, traj, rig, render)
    sensor = make_sensors(SensorConfig.from_dict(_conf("sensor")), render, 1, 0.0, 0)[0][0]
    fronts = {"orb": make_frontend("orb", _conf("features")["orb"])}
    return scene, sensor, fronts, xs.pose_frames(city, traj)


@pytest.fixture(scope="module")
def sweeps(world):
    scene, sensor, fronts, frames = world
    out = {}
    for pose in ("open_road", "tunnel"):
        y = scene.luminance(frames[pose], 75.0, 1) @ xs.Y_RGB
        out[pose] = (xs.sweep_exposure(scene, sensor, frames[pose], fronts), y)
    return out


def test_grids():
    e = xs.exposure_grid_us(0.5)
    assert e[0] == 75.0 and e[-1] == 30000.0 and len(e) == 19  # 8.64 stops: 17 half stops + the 30 ms end
    assert np.allclose(np.diff(np.log2(e))[:-1], 0.5)
    g = xs.gain_grid_db(0.5)
    assert g[-1] == 30.0 and np.isclose(g[0], xs.DB_PER_EV / 2)
    for t, gain in xs.equal_brightness_settings(2400.0, [0.0, 6.0, 30.0]):
        assert t * 10 ** (gain / 20) == pytest.approx(2400.0)


def test_open_road_inliers_form_an_inverted_u(sweeps):
    points, _ = sweeps["open_road"]
    n = [p.n_inliers["orb"] for p in points]
    k = int(np.argmax(n))
    assert 0 < k < len(n) - 1, n
    # short end: the sunlit road is already mid-grey at 75 µs, so only ~2 EV of the rising side (shot/read noise and
    # 8-bit quantisation of the darker areas) lies in the range — still a clear drop
    assert n[0] <= 0.75 * n[k], n
    # long end: 30 ms in sunlight clips nearly the whole frame, few gradients are left to detect. Not all: under the
    # CIE clear sky (issue 23) traversal 0's 32° sun gives 11 klux of skylight (the overcast profile gave 25 klux),
    # so shadowed surfaces read ~0.1·11k/π ≈ 400 cd/m² and the darkest of them stay below saturation (measured 95.6 %
    # clipped, 40 inliers against 457 at the peak)
    assert points[-1].saturated_fraction > 0.9 and n[-1] <= 0.15 * n[k], n


@pytest.mark.xfail(strict=True, reason="on the calibrated camera (f/5.8, 59.1°, portal daylight) the tunnel pose's ORB "
                   "curve is flat with two humps (120–136 inliers from 2.5 to 6.5 EV and again at 30 ms + 30 dB): the "
                   "first, set by the portal-lit walls, wins, 1.5 EV above the road's peak, while the p95 ratio is "
                   "6.7 EV. It held on the old camera (70°, f/2); see `benchmarks/archive/exposure_response.py`")
def test_tunnel_peak_moves_by_the_luminance_ratio(sweeps):
    """The rising side of the U is set by noise in the bulk of the image, the falling side by clipping of its
    brightest few per cent (measured clipped share at the peaks: 3–6 %). So the peak moves by at least the ratio of the
    bright ends (95th percentiles) and at most by the ratio of the medians, within the grid tolerance.

    Holds for this traversal; not a general law of the simulator: at 320×240 the benchmark measures ORB shifts of
    6.0 / 4.0 / 4.5 / 4.5 EV on traversals 0–3 against p95 ratios of 5.9 / 5.9 / 5.8 / 7.1 EV (traversals 1 and 3
    below the bracket by 1.9 and 2.6 EV) and median ratios of 8.3–9.1 EV."""
    (road, y_road), (tunnel, y_tunnel) = sweeps["open_road"], sweeps["tunnel"]
    shift_ev = xs.peak(tunnel, "orb").ev - xs.peak(road, "orb").ev
    median_ev = np.log2(np.median(y_road) / np.median(y_tunnel))
    p95_ev = np.log2(np.percentile(y_road, 95) / np.percentile(y_tunnel, 95))
    assert median_ev > 7.0  # the tunnel interior really is far darker than sunlit road
    assert p95_ev - TOL_EV <= shift_ev <= median_ev + TOL_EV, (shift_ev, p95_ev, median_ev)


@pytest.mark.xfail(strict=True, reason="spec expectation not met: the tunnel's peak moves ~6.5 EV, the median "
                   "luminance ratio is ~9.1 EV — lamps and the exit portal clip first (see benchmarks/archive/exposure_response)")
def test_tunnel_peak_moves_by_the_median_luminance_ratio(sweeps):
    (road, y_road), (tunnel, y_tunnel) = sweeps["open_road"], sweeps["tunnel"]
    shift_ev = xs.peak(tunnel, "orb").ev - xs.peak(road, "orb").ev
    assert abs(shift_ev - np.log2(np.median(y_road) / np.median(y_tunnel))) <= TOL_EV


def test_gain_at_equal_brightness_raises_false_detections(world):
    """Same t·gain, so the same mean image; but 1/gain fewer electrons: relative shot noise grows as √gain and read
    noise is amplified with the signal. A flat field at 5 % of saturation holds ~520 e⁻ at 0 dB (σ ≈ 1.4 grey
    levels: FAST's threshold of 20 is out of reach) and ~16 e⁻ at 30 dB (σ ≈ 4.9 e⁻ ≈ 10 grey levels)."""
    scene, sensor, fronts, frames = world
    fronts = dict(fronts, viso=make_frontend("viso", _conf("features")["viso"]))
    eff_us = 13576.0  # ≈ the tunnel's peak; 30 dB leaves 429 µs, inside the range
    settings = xs.equal_brightness_settings(eff_us, [0.0, 18.0, 24.0, 30.0])
    lum = xs.flat_field_luminance_cd_m2(sensor, eff_us, 0.05)
    flat = [xs.flat_field_detections(sensor, lum, t, g, fronts) for t, g in settings]
    greys = [g for _, g in flat]
    # equal means up to the sRGB curve's concavity acting on the larger noise (Jensen: a slightly lower mean)
    assert max(greys) - min(greys) < 2.0, greys
    orb = [d["orb"] for d, _ in flat]
    viso = [d["viso"] for d, _ in flat]
    assert orb[0] == 0 and viso[0] == 0, (orb, viso)
    assert orb[-1] >= 20 and viso[2] >= 10, (orb, viso)
    assert viso == sorted(viso), viso
    # on the tunnel pose, features that no match explains grow with gain
    pts = xs.sweep_settings(scene, sensor, frames["tunnel"], [settings[0], settings[-1]], {"orb": fronts["orb"]})
    unmatched = [p.n_features["orb"] - p.n_inliers["orb"] for p in pts]
    assert abs(pts[0].mean_grey - pts[1].mean_grey) < 2.0
    assert unmatched[1] > 1.5 * unmatched[0], unmatched
