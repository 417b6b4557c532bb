"""Renderer speed-ups change nothing: the reach test before block/prop intersections (Renderer.cull), the spread row
order of the parallel loops and the bit-mask texture wrap give the same images, bit for bit, as the exact paths."""

import math

import numba
import numpy as np
import pytest

from expoctl.world import RenderConfig, Renderer, load_city
from expoctl.world import raycast as rc
from expoctl.world.raycast import PROP, SIDE, SKY, TCEIL, TWALL, spread_stride
from render_poses import tunnel_poses


def _poses(city):
    return tunnel_poses(city, portal_offset_m=1.0)


@pytest.fixture(scope="module", params=["train", "test"])
def scene(request):
    """Sunny traversal (shadow rays walk the roadside too); the test city has a curved arch tunnel."""
    city = load_city(request.param)
    traj = next(t for t in (city.traversal(i, 40, fps=15.0, seed=0) for i in range(8)) if not t.conditions.overcast)
    return city, traj, Renderer(city, RenderConfig(width=96, height=72, hfov_deg=70.0), conditions=traj.conditions)


def _render(r, pose, cull):
    r.cull = cull
    try:
        return r.render_full(pose, glare=False)
    finally:
        r.cull = True


def test_cull_gives_the_exact_image(scene):
    city, _, r = scene
    codes = set()
    for pose in _poses(city):
        fast, exact = _render(r, pose, True), _render(r, pose, False)
        for key in ("luminance", "depth", "code", "material"):
            np.testing.assert_array_equal(fast[key], exact[key], err_msg=key)
        codes |= set(np.unique(exact["code"]).tolist())
    # the poses exercise what the reach test skips (roadside blocks, props) and the tunnel and sky paths
    assert {SKY, SIDE, PROP, TWALL, TCEIL} <= codes


def test_cull_gives_the_exact_motion_blur(scene):
    _, traj, r = scene
    for method in ("fast", "reference"):
        r._cache.clear()
        r.cull = False
        try:
            exact = r.render_exposure(traj, 6, 20000.0, method=method)
        finally:
            r.cull = True
        r._cache.clear()
        np.testing.assert_array_equal(r.render_exposure(traj, 6, 20000.0, method=method), exact)


def test_spread_stride_is_a_balanced_permutation():
    for n in (1, 2, 3, 6, 24, 48, 72, 120, 240, 480, 481, 1080):
        s = spread_stride(n)
        rows = (np.arange(n) * s) % n
        np.testing.assert_array_equal(np.sort(rows), np.arange(n))
        if n >= 24:  # each half of the iterations (one thread's share of two) covers both halves of the image
            first = rows[: n // 2]
            assert abs(np.mean(first < n // 2) - 0.5) < 0.1


def test_thread_count_does_not_change_the_image(scene):
    city, traj, r = scene
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = r.render_full(traj.poses[3], glare=False)["luminance"]
        one_blur = (r._cache.clear(), r.render_exposure(traj, 3, 20000.0))[1]
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        many = r.render_full(traj.poses[3], glare=False)["luminance"]
        many_blur = (r._cache.clear(), r.render_exposure(traj, 3, 20000.0))[1]
    finally:
        numba.set_num_threads(before)
    np.testing.assert_array_equal(one, many)
    np.testing.assert_array_equal(one_blur, many_blur)


def _bilinear_modulo(tile, x, y):
    """Reference bilinear sample with Python's modulo wrap (the texture tile is periodic)."""
    n = tile.shape[0]
    x, y = x - 0.5, y - 0.5
    fx, fy = math.floor(x), math.floor(y)
    ax, ay = x - fx, y - fy
    x0, y0 = int(fx) % n, int(fy) % n
    x1, y1 = (x0 + 1) % n, (y0 + 1) % n
    return (tile[y0, x0] * (1 - ax) + tile[y0, x1] * ax) * (1 - ay) + (tile[y1, x0] * (1 - ax) + tile[y1, x1] * ax) * ay


def test_texture_wrap_mask_equals_modulo():
    rng = np.random.default_rng(0)
    for n in (1, 2, 8, 64):
        tile = rng.integers(0, 256, (n, n, 3)).astype(np.uint8)
        texels = np.concatenate([np.zeros(5, np.uint8), tile.ravel()])  # level at a non-zero offset, as in the atlas
        for x, y in rng.uniform(-3.0 * n, 3.0 * n, (200, 2)):
            out = np.zeros(3)
            rc._bilinear(texels, 5, n, x, y, out, 1.0)
            np.testing.assert_array_equal(out, _bilinear_modulo(tile.astype(np.float64), x, y))


@pytest.mark.parametrize("exposure_us", [75.0, 300.0, 2000.0, 20000.0])
def test_still_frames_skip_the_smear_with_the_same_result(scene, exposure_us):
    """_smear skips the taps when no flow component reaches 0.5 px (_flow_reaches): the decision equals the one
    from _blur_kernel's own maximum, and render_exposure returns what the always-smear code returned."""
    from expoctl.world.renderer import _blur_kernel, _flow_reaches

    _, traj, r = scene
    decisions = set()
    for k in (2, 6, 12):
        r._cache.clear()
        got = r.render_exposure(traj, k, exposure_us)
        sharp = next(iter(r._cache.values()))
        t0 = float(traj.timestamps_ns[k]) * 1e-9
        pa, pb = traj.pose_at(t0), traj.pose_at(t0 + exposure_us * 1e-6)
        K = r.K
        args = (sharp["depth"], K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.ascontiguousarray(sharp["pose"]),
                np.ascontiguousarray(pa), np.ascontiguousarray(pb))
        out = np.empty_like(sharp["luminance"])
        max_shift = _blur_kernel(np.ascontiguousarray(sharp["luminance"]), *args, out)  # the always-smear path
        assert _flow_reaches(*args, 0.5) == (max_shift >= 0.5)
        for limit in (0.5 * max_shift, max_shift, np.nextafter(max_shift, np.inf)):
            assert _flow_reaches(*args, limit) == (max_shift >= limit)
        expected = r.apply_glare(out if max_shift >= 0.5 else sharp["luminance"])
        np.testing.assert_array_equal(got, expected)
        decisions.add(bool(max_shift >= 0.5))
    if exposure_us >= 20000.0:
        assert decisions == {True}  # a moving frame at this exposure: the smear runs
    if exposure_us == 75.0:
        assert decisions == {False}  # and at the shortest exposure it is skipped
