"""Renderer: absolute luminance per zone (spec ranges), determinism, veiling glare, motion-blur fast path vs reference."""

import math
from pathlib import Path

import numpy as np
import pytest

from expoctl.errors import ConfigError
from expoctl.world import RenderConfig, Renderer, intrinsics, load_city, make_renderer
from expoctl.world.shade import MAT_LAMP, MAT_SKY

Y_RGB = np.array([0.2126, 0.7152, 0.0722])
ROAD, TUNNEL_WALL = 0, 7


@pytest.fixture(scope="module")
def train():
    city = load_city("train")
    traj = city.traversal(0, 60, fps=15.0, seed=0)
    assert not traj.conditions.overcast and traj.conditions.sun_direction[2] > 0.3
    return city, traj, Renderer(city, RenderConfig(width=160, height=120, hfov_deg=70.0), conditions=traj.conditions)


def _view(renderer, city, s):
    out = renderer.render_full(city.pose_at_s(s, 0.0))
    return out["luminance"] @ Y_RGB, out["material"], out["depth"]


def test_intrinsics():
    K = intrinsics(640, 480, 90.0)
    assert K[0, 0] == pytest.approx(320.0) and K[1, 1] == pytest.approx(320.0)
    assert (K[0, 2], K[1, 2]) == (320.0, 240.0)
    with pytest.raises(ConfigError, match="hfov_deg"):
        intrinsics(640, 480, 0.0)


def test_outdoor_levels(train):
    city, traj, r = train
    Y, mat, depth = _view(r, city, 250.0)  # open straight, far from both tunnels
    road = (mat == ROAD) & (depth < 25)
    c = traj.conditions
    # measured per 100 klux of global horizontal illuminance (van Bommel, Road Lighting 2015, Table 20.1, after
    # CIE 88): road 3–5 kcd/m², clear sky near the horizon 8–16 kcd/m². This traversal's sun is at 32° (global
    # ≈ 55 klux), so the spec's "sunlit road 2–4 kcd/m²" (for ~100 klux) scales down with it.
    per_100klux = 1.0e5 / c.global_illuminance_lux
    assert 3000 <= np.median(Y[road]) * per_100klux <= 5000
    assert 8000 <= np.median(Y[mat == MAT_SKY]) * per_100klux <= 16000
    # Lambertian check: the sunlit road equals albedo·E/π within the texture's spread
    expected = city.cfg["albedo"]["road"] * (c.sky_illuminance_lux + c.sun_illuminance_lux * c.sun_direction[2]) / math.pi
    assert np.median(Y[road]) == pytest.approx(expected, rel=0.25)


def test_tunnel_interior_lamps_and_threshold_zone(train):
    city, _, r = train
    start = city.cfg["tunnels"][0]["start_m"]
    Y, mat, depth = _view(r, city, start + 45.0)  # past threshold (15 m) + transition (20 m) zones
    near = depth < 12
    assert 2 <= np.median(Y[(mat == ROAD) & near]) <= 10  # interior 2–10 cd/m²
    assert np.percentile(Y[(mat == TUNNEL_WALL) & near], 95) <= 60  # "up to ~50 near lamps" (measured p95 ≈ 52)
    # look straight up under an interior lamp: the panel fills the centre at its configured luminance
    spacing = city.cfg["lamps"]["spacing_m"]
    pose = city.pose_at_s(start + 0.5 * spacing + 6 * spacing, 0.0)
    pose[:3, 3] -= pose[:3, 0] * city.lane_offset_m  # under the centreline lamp row
    pose[:3, :3] = pose[:3, :3] @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]])
    up = r.render_full(pose, glare=False)
    assert up["material"][60, 80] == MAT_LAMP
    assert up["luminance"][58:62, 78:82] @ Y_RGB == pytest.approx(city.cfg["lamps"]["luminance_cd_m2"], rel=1e-3)
    # CIE 88 threshold zone: road a small fraction k of the access-zone luminance (reinforced lamps + daylight)
    Y_th, mat_th, depth_th = _view(r, city, start + 2.0)
    l_access = np.median(_view(r, city, 250.0)[0][(_view(r, city, 250.0)[1] == ROAD)])
    th = np.median(Y_th[(mat_th == ROAD) & (depth_th < 8)])
    assert 0.02 * l_access <= th <= 0.2 * l_access
    assert th > 5 * np.median(Y[(mat == ROAD) & near])


def test_tunnel_exit_scene_range(train):
    city, _, r = train
    out = r.render_full(city.pose_at_s(city.cfg["tunnels"][0]["start_m"] + 40.0, 0.0), glare=False)
    Y = out["luminance"] @ Y_RGB  # scene luminance (before lens glare), mid-tunnel looking at the exit
    range_db = 20 * np.log10(Y.max() / Y.min())
    assert 88 <= range_db <= 110  # spec: 90–100 dB per frame at a tunnel exit


def test_daylight_tail_decays_inside_portal(train):
    city, _, r = train
    start = city.cfg["tunnels"][0]["start_m"]
    levels = []
    for x in (5.0, 15.0, 30.0, 45.0):
        pose = city.pose_at_s(start + x, 0.0)
        pose[:3, :3] = pose[:3, :3] @ np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]])  # look straight down
        out = r.render_full(pose, glare=False)
        levels.append(np.median(out["luminance"][40:80, 60:100] @ Y_RGB))
    assert levels[0] > levels[1] > levels[2]
    assert levels[0] > 5 * levels[3]


def test_determinism_and_glare(train):
    city, traj, r = train
    a = r.render_full(traj.poses[10], glare=False)["luminance"]
    b = r.render_full(traj.poses[10], glare=False)["luminance"]
    np.testing.assert_array_equal(a, b)
    g = r.apply_glare(a)
    assert g.sum() == pytest.approx(a.sum(), rel=0.02)  # glare redistributes, it does not create light
    assert g.min() > a.min()
    halo = (g - (1 - r.glare_fraction) * a) / r.glare_fraction
    assert halo.max() < a.max()


def test_blur_fast_path_matches_reference(train):
    """Fast path (one render + smear along ego-motion flow) vs reference (sub-frame averaging), 30 ms at speed.
    Error metric: mean |Δ log(1 + Y)|; the fast path must close most of the gap between a sharp frame and the
    reference. Measured (160×120, train traversal 0): fast ≈ 0.039, sharp ≈ 0.049."""
    city, traj, _ = train
    r = Renderer(city, RenderConfig(width=160, height=120, hfov_deg=70.0, glare_fraction=0.0), conditions=traj.conditions)
    t0 = traj.timestamps_ns[5] * 1e-9
    ref = r.render_exposure(traj, 5, 30000.0, method="reference") @ Y_RGB
    fast = r.render_exposure(traj, 5, 30000.0, method="fast") @ Y_RGB
    sharp = r.render_full(traj.pose_at(t0 + 0.015), glare=False)["luminance"] @ Y_RGB

    def err(a):
        return float(np.mean(np.abs(np.log1p(a) - np.log1p(ref))))

    assert err(fast) < 0.85 * err(sharp)
    assert err(fast) < 0.06
    # short exposures are sharp: the fast path returns the mid-exposure render
    short = r.render_exposure(traj, 5, 100.0) @ Y_RGB
    np.testing.assert_allclose(short, r.render_full(traj.pose_at(t0 + 50e-6), glare=False)["luminance"] @ Y_RGB,
                               rtol=1e-5)


def test_second_camera_offset(train):
    city, traj, r = train
    a = r.render_exposure(traj, 3, 1000.0)
    b = r.render_exposure(traj, 3, 1000.0, camera_offset_m=0.0392)
    assert not np.array_equal(a, b)
    assert np.median(np.abs(a - b) / (a + 1)) < 0.2  # 3.92 cm apart: nearly the same view


def test_render_config_errors(train):
    city, _, _ = train
    with pytest.raises(ConfigError, match="world.render.blur"):
        make_renderer(city, {"blur": "smudge"})
    with pytest.raises(ConfigError, match="world.render.colour"):
        make_renderer(city, {"colour": True})


SHARED = Path(__file__).resolve().parents[3] / "shared" / "data" / "hdri"


def test_hdri_sky():
    path = SHARED / "kloppenheim_05_1k.hdr"
    if not path.is_file():
        pytest.skip("shared HDRI examples absent")
    city = load_city({"base": "train", "name": "hdri", "traversal": {
        "hdri": {"path": str(path), "median_cd_m2": 5000.0, "azimuth_deg": 30.0}}})
    traj = city.traversal(0, 5)
    r = Renderer(city, RenderConfig(width=160, height=120, hfov_deg=70.0), conditions=traj.conditions)
    out = r.render_full(city.pose_at_s(250.0, 0.0), glare=False)
    sky = out["luminance"][out["material"] == MAT_SKY] @ Y_RGB
    assert 1000 < np.median(sky) < 25000  # rescaled to an absolute level around the configured median
    assert r.lp[4] > 0  # sky illuminance integrated from the map lights the road


def test_missing_hdri_file():
    from expoctl.world.sky import load_hdri
    with pytest.raises(ConfigError, match="world.city.traversal.hdri.path"):
        load_hdri("/nonexistent/sky.hdr")


def test_shared_render_serves_second_camera(train):
    """share_render: camera 2 (3.92 cm right, other exposure) warped from camera 1's render. Measured log-error vs
    camera 2's own reference ≈ 0.045 (both 30 ms) and ≈ 0.08 (camera 2 at 0.2 ms: pure parallax warp)."""
    city, traj, _ = train
    r = Renderer(city, RenderConfig(width=160, height=120, hfov_deg=70.0, glare_fraction=0.0, share_render=True), conditions=traj.conditions)
    r.render_exposure(traj, 5, 30000.0)
    cam2 = r.render_exposure(traj, 5, 30000.0, camera_offset_m=0.0392) @ Y_RGB
    assert len(r._cache) == 1  # one render served both cameras
    ref2 = r.render_exposure(traj, 5, 30000.0, camera_offset_m=0.0392, method="reference") @ Y_RGB
    assert float(np.mean(np.abs(np.log1p(cam2) - np.log1p(ref2)))) < 0.07


def test_render_cache_never_mixes_trajectories(train):
    import pickle
    city, traj, r = train
    other = city.traversal(7, 60, fps=15.0, seed=3)
    other.conditions = traj.conditions  # same lighting: only the cache key can tell them apart
    a = r.render_exposure(traj, 4, 20000.0)
    b = r.render_exposure(other, 4, 20000.0)
    assert not np.allclose(a, b)
    assert len(pickle.dumps(other)) < 2_000_000  # trajectories (with their city) stay small to send to workers


def test_mip_mapping_suppresses_aliasing_flicker(train):
    """Distant texels under a sub-pixel camera shift: with mip-mapping the frame-to-frame change stays small;
    point-sampling the finest level (mip_bias→0) flickers."""
    city, traj, _ = train
    pose_a = city.pose_at_s(250.0, 0.0)
    pose_b = pose_a.copy()
    pose_b[:3, 3] += pose_a[:3, 0] * 0.02  # 2 cm sideways: < 0.1 px at 40 m
    flicker = {}
    for bias in (1.0, 0.02):
        r = Renderer(city, RenderConfig(width=160, height=120, hfov_deg=70.0, mip_bias=bias, glare_fraction=0.0), conditions=traj.conditions)
        a, b = (r.render_full(p, glare=False) for p in (pose_a, pose_b))
        far = (a["depth"] > 40) & np.isfinite(a["depth"]) & (a["material"] < 200)
        ya, yb = a["luminance"] @ Y_RGB, b["luminance"] @ Y_RGB
        flicker[bias] = float(np.mean(np.abs(ya - yb)[far] / (ya[far] + yb[far])))
    assert flicker[1.0] < 0.5 * flicker[0.02]
