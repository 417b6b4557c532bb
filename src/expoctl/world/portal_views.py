"""Small renders at each tunnel that set its lighting for a traversal's conditions (Renderer.set_conditions):

- portal_luminances: the mean luminance seen through each portal opening, looking out — what the daylight term
  (expoctl.world.daylight) multiplies with the opening's configuration factor — separately for rays rising and rays
  descending: a tunnel surface point sees the opening's part above its own height with rising rays (the approach
  walls, facades, sky) and the part below with descending ones (the road and ground outside); the road inside sees
  only the first, the ceiling mostly the second, and they differ ~2–4× (a shaded approach road vs a bright sky).
  Estimate: a 48×48 pinhole view with a 90° field of view from the centre of the opening (centreline, half the tunnel
  height), looking out along the tunnel axis; the plain pixel mean of its upper and of its lower half (the horizon is
  the image's middle row boundary). A pixel's solid angle goes as cos³ of its angle from the axis, so the mean weights
  the directions near the axis (all a deep point sees through the opening) most and covers the ±45° a point 5 m
  inside sees. It holds the real outside scene: sunlit/shaded road, the approach cutting, facades, sky.
- access_luminance_l20: CIE 88's access-zone luminance L20 — the mean luminance in a cone of 20° apex (10° half
  angle) at the eye of an approaching driver at the stopping distance before the portal, centred on a point at a
  quarter of the height of the tunnel mouth (CIE e-ILV 17-31-088 'access zone luminance'), on the road centreline.
  The eye is on the lane of travel at the traversal's camera height; rendered 64×64 over a 22° field (the cone plus
  a pixel of margin), lamps at their nominal level (the zoning this L20 sets is not known yet).

Both exclude the sun's disk: the direct sun is traced per pixel by the shadow ray (no double counting inside the
tunnel), and for L20 a 0.53° disk at ~10⁹ cd/m² would swamp the adaptation luminance the 20° mean stands for.
All renders use the numba kernel (also under the GL backend), so both backends get the same lighting.
"""

from __future__ import annotations

import math

import numpy as np

from expoctl.world import raycast as rc
from expoctl.world.render_config import intrinsics
from expoctl.world.shade import render_kernel

_Y = np.array([0.2126, 0.7152, 0.0722])
OPENING_VIEW_PX, OPENING_VIEW_FOV_DEG = 48, 90.0
L20_VIEW_PX, L20_VIEW_FOV_DEG, L20_HALF_ANGLE_DEG = 64, 22.0, 10.0
L20_AIM_HEIGHT_FRACTION = 0.25  # CIE: the cone is centred at a quarter of the height of the tunnel mouth


def cone_mean(lum_y: np.ndarray, K: np.ndarray, half_angle_deg: float) -> float:
    """Solid-angle-weighted mean of a pinhole image (H, W) over the pixels whose ray lies within half_angle_deg of the
    optical axis. A pixel at angle θ from the axis spans dω = cos³θ·dA/f² (dA: pixel area), hence the cos³θ weight."""
    h, w = lum_y.shape
    xs = (np.arange(w) + 0.5 - K[0, 2]) / K[0, 0]
    ys = (np.arange(h) + 0.5 - K[1, 2]) / K[1, 1]
    tan2 = xs[None, :] ** 2 + ys[:, None] ** 2
    cos_t = 1.0 / np.sqrt(1.0 + tan2)
    inside = cos_t >= math.cos(math.radians(half_angle_deg))
    weight = np.where(inside, cos_t ** 3, 0.0)
    return float((lum_y * weight).sum() / weight.sum())


def _look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera-to-world pose at eye looking at target, image x to the right and y down (world z up)."""
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    pose[:3, 3] = eye
    return pose


def _centre_frame(city, s):
    """Centreline point, forward and up axes at arc length s."""
    x, y, z, psi, dz = (float(np.asarray(a)) for a in city.route.centre(s))
    g = math.atan(dz)
    fwd = np.array([math.cos(psi) * math.cos(g), math.sin(psi) * math.cos(g), math.sin(g)])
    right = np.array([math.sin(psi), -math.cos(psi), 0.0])
    return np.array([x, y, z]), fwd, np.cross(right, fwd)


def render_y(renderer, pose, size_px, fov_deg, lp, lamp_mult, portal_lum) -> tuple[np.ndarray, np.ndarray]:
    """(luminance Y (size, size) cd/m², K) of a square numba render with the given lighting (no glare)."""
    K = intrinsics(size_px, size_px, fov_deg)
    i0, inside = renderer.locate(pose[:3, 3])
    lum = np.empty((size_px, size_px, 3), np.float32)
    depth = np.empty((size_px, size_px), np.float32)
    code = np.empty((size_px, size_px), np.uint8)
    mat = np.empty((size_px, size_px), np.uint8)
    render_kernel(renderer.seg, lp, renderer.texels, renderer.offs, renderer.sizes, renderer.scales,
                  renderer.albedo, lamp_mult, renderer._lamp_count, portal_lum, renderer.light_map, renderer.hdri,
                  np.ascontiguousarray(pose[:3, 3]), np.ascontiguousarray(pose[:3, :3]), K[0, 0], K[1, 1], K[0, 2],
                  K[1, 2], i0, inside, lum, depth, code, mat, renderer.cull)
    return lum.astype(np.float64) @ _Y, K


def _no_sun_disk(lp: np.ndarray) -> np.ndarray:
    out = lp.copy()
    out[rc.LP_SUN_DISK_L] = 0.0
    return out


def portal_luminances(renderer, lp: np.ndarray) -> np.ndarray:
    """(n_tunnels, 2, 2) mean luminance (cd/m²) seen out of each tunnel's [start, end] opening, [looking up, looking
    down] (module docstring)."""
    city = renderer.city
    tunnels = city.cfg["tunnels"]
    out = np.zeros((max(1, len(tunnels)), 2, 2))
    lp = _no_sun_disk(lp)
    ones = np.ones((len(renderer._lamp_count), int(renderer._lamp_count.max())))  # lamps at nominal
    for ti, t in enumerate(tunnels):
        a, length, h = float(t["start_m"]), float(t["length_m"]), float(t["height_m"])
        for end, (s, sign) in enumerate(((a - 0.05, -1.0), (a + length + 0.05, 1.0))):
            # 5 cm outside the portal plane, so the camera is in the open segment looking away from the tunnel
            p, fwd, up = _centre_frame(city, s)
            eye = p + up * (0.5 * h)
            y, _ = render_y(renderer, _look_at(eye, eye + sign * fwd), OPENING_VIEW_PX, OPENING_VIEW_FOV_DEG, lp,
                            ones, out)
            half = OPENING_VIEW_PX // 2  # image rows above the principal point look up, the rest down
            out[ti, end] = float(y[:half].mean()), float(y[half:].mean())
    return out


def access_luminance_l20(renderer, lp: np.ndarray, portal_lum: np.ndarray, stopping_distance_m: float) -> np.ndarray:
    """CIE 88 L20 (cd/m²) of each tunnel's entry portal (the start, driven in +s), from the stopping distance."""
    city = renderer.city
    out = []
    lp = _no_sun_disk(lp)
    ones = np.ones((len(renderer._lamp_count), int(renderer._lamp_count.max())))  # lamps at nominal
    cam_h = float(city.cfg["traversal"]["camera_height_m"])
    for t in city.cfg["tunnels"]:
        a, h = float(t["start_m"]), float(t["height_m"])
        p, _, up = _centre_frame(city, a)
        target = p + up * (L20_AIM_HEIGHT_FRACTION * h)
        q, fwd_e, up_e = _centre_frame(city, city.route.wrap(a - stopping_distance_m))
        right_e = np.cross(fwd_e, up_e)
        eye = q + right_e * city.lane_offset_m + up_e * cam_h
        y, K = render_y(renderer, _look_at(eye, target), L20_VIEW_PX, L20_VIEW_FOV_DEG, lp, ones, portal_lum)
        out.append(cone_mean(y, K, L20_HALF_ANGLE_DEG))
    return np.array(out)
