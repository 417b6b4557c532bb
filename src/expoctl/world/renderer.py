"""Renderer: scene luminance (cd/m², linear RGB with Y = 0.2126R + 0.7152G + 0.0722B) and depth for a pose, and the
exposure-averaged (motion-blurred) luminance a global-shutter camera integrates over [t, t + exposure].

Motion blur: `blur="reference"` averages sub-frame renders across the exposure interval (enough sub-frames that
consecutive ones move < 0.5 px); `blur="fast"` renders once at mid-exposure and smears each pixel along its
ego-motion flow (from depth and the analytic trajectory). tests/world/test_renderer.py states the fast path's error
against the reference.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numba import njit, prange

from expoctl.world import clear_sky, daylight, portal_views
from expoctl.world import raycast as rc
from expoctl.world import route as rt
from expoctl.world.city import SUN_DISK_SOLID_ANGLE_SR, City, Conditions, Trajectory
from expoctl.world.cities import MATERIALS
from expoctl.world.render_config import RenderConfig, intrinsics
from expoctl.world.shade import render_kernel
from expoctl.world.sky import hdri_for

_Y = np.array([0.2126, 0.7152, 0.0722])


def _rgb_norm(rgb):
    rgb = np.asarray(rgb, dtype=np.float64)
    return rgb / float(rgb @ _Y)


class Renderer:
    """Render a city from camera poses, with the options of `world.render` (`RenderConfig`, the one definition of
    their defaults and bounds; its `backend` key is make_renderer's choice of class).

    width, height: pixels; hfov_deg: horizontal field of view; glare_fraction: share of image luminance scattered
    by the lens into a wide halo (veiling glare, 0.1–1 %); mip_bias: texture footprint multiplier (>1 blurs more,
    <1 sharper but aliasing); blur: 'fast' or 'reference'; share_render: in the fast path, one sharp render per
    frame serves both cameras and all exposures (warped by depth-based flow): about half the cost of a stereo
    rig, but the resampling softens the warped camera relative to the rendered one, so it is off by default;
    portal_daylight: 'exact' or 'light_map' (the portals' configuration factors from a per-tunnel table; opt-in).
    """

    def __init__(self, city: City, render: RenderConfig | None = None, conditions: Conditions | None = None):
        render = (RenderConfig() if render is None else render).validated()
        self.config = render  # (not `render`: that is the method)
        self.K = intrinsics(render.width, render.height, render.hfov_deg)
        self.city, self.width, self.height, self.hfov_deg = city, render.width, render.height, float(render.hfov_deg)
        self.glare_fraction, self.blur, self.max_subframes = float(render.glare_fraction), render.blur, render.max_subframes
        self.share_render = bool(render.share_render)
        self.n_sharp_renders = 0  # sharp renders of the fast blur path (the cost render sharing saves)
        self.seg = np.ascontiguousarray(city.segments)
        self.texels, self.offs, self.sizes, self.scales = city.texture_atlas()
        if np.any(self.sizes & (self.sizes - 1)):  # raycast._bilinear wraps texel indices with a bit mask
            raise ValueError("texture mip level sizes must be powers of two (textures.tile_px)")
        cfg = city.cfg
        self.albedo = np.array([float(cfg["albedo"][m]) for m in MATERIALS])
        self._base_lp = self._static_lighting(cfg, render.mip_bias, render.tmax_m)
        self._lamp_count, self._e_nom = self._lamp_layout(cfg)
        # per-tunnel table of the portal configuration factors (daylight.light_map), or an empty one: exact per pixel
        self.light_map = (daylight.light_map(self.seg, len(self._lamp_count)) if render.portal_daylight == "light_map"
                          else daylight.NO_LIGHT_MAP)
        self._cache: dict = {}
        self._lighting_cache: dict = {}  # conditions → (portal luminances, L20 per tunnel): see _portal_lighting
        # reach test before each roadside block/prop intersection (same image; False = exact test for every one,
        # the reference path tests/world/test_renderer_speedups.py compares against)
        self.cull = True
        self.set_conditions(conditions if conditions is not None else city.conditions(0, 0))

    # ------------------------------------------------------------------ lighting setup
    def _static_lighting(self, cfg, mip_bias, tmax_m):
        lp = np.zeros(rc.LP_N)
        lamps, light, road = cfg["lamps"], cfg["lighting"], cfg["road"]
        lp[rc.LP_LAMP_L] = float(lamps["luminance_cd_m2"])
        lp[rc.LP_LAMP_RGB:rc.LP_LAMP_RGB + 3] = _rgb_norm(lamps["colour_rgb"])
        lp[rc.LP_LAMP_LEN], lp[rc.LP_LAMP_W] = float(lamps["length_m"]), float(lamps["width_m"])
        lp[rc.LP_LAMP_SPACING] = float(lamps["spacing_m"])
        rows = [float(v) for v in lamps["rows_v_m"]][:4]
        lp[rc.LP_N_ROWS] = len(rows)
        lp[rc.LP_ROWS:rc.LP_ROWS + len(rows)] = rows
        lp[rc.LP_TAIL_M], lp[rc.LP_TAIL_FRAC] = float(light["daylight_tail_m"]), float(light["daylight_tail_fraction"])
        lp[rc.LP_INTERREFL] = float(light["interreflection"])
        lp[rc.LP_ROAD_HALF] = road["lanes"] * road["lane_width_m"] / 2 + road["shoulder_m"]
        lp[rc.LP_LANE_W], lp[rc.LP_LANES], lp[rc.LP_SIDEWALK] = road["lane_width_m"], road["lanes"], road["sidewalk_m"]
        lp[rc.LP_TEXEL_M], lp[rc.LP_TILE_PX] = float(cfg["textures"]["texel_m"]), float(cfg["textures"]["tile_px"])
        lp[rc.LP_MIP_BIAS], lp[rc.LP_TMAX] = float(mip_bias), float(tmax_m)
        lp[rc.LP_ZTOP] = float(max(self.seg[:, rt.HILL_H].max(), self.seg[:, rt.L_H].max(), self.seg[:, rt.R_H].max())
                               + 0.5)
        return lp

    def _lamp_layout(self, cfg):
        spacing = float(cfg["lamps"]["spacing_m"])
        counts = np.array([max(1, int((float(t["length_m"]) - 0.5 * spacing) // spacing) + 1) for t in cfg["tunnels"]]
                          or [1], dtype=np.int64)
        # nominal road illuminance between two interior lamps (all multipliers 1), lane centre, for CIE 88 zoning
        e_nom = []
        area = float(cfg["lamps"]["length_m"]) * float(cfg["lamps"]["width_m"])
        for t in cfg["tunnels"] or [{"height_m": 5.0}]:
            h = float(t["height_m"]) - 0.05
            e = 0.0
            for k in range(-6, 7):
                du = (k + 0.5) * spacing
                for vr in cfg["lamps"]["rows_v_m"]:
                    dv = float(vr) - self.city.lane_offset_m
                    hh = h if t.get("profile", "box") == "box" else 0.95 * h
                    r2 = du * du + dv * dv + hh * hh
                    e += float(cfg["lamps"]["luminance_cd_m2"]) * area * (hh / math.sqrt(r2)) ** 2 / r2
            e_nom.append(e)
        return counts, np.array(e_nom)

    def set_conditions(self, conditions: Conditions) -> None:
        """Set sun, sky and lamp zoning (CIE 88 threshold/transition reinforcement depends on outside daylight)."""
        cfg, lp = self.city.cfg, self._base_lp.copy()
        lp[0:3] = conditions.sun_direction
        lp[rc.LP_E_SUN] = conditions.sun_illuminance_lux if conditions.sun_direction[2] > 0 else 0.0
        lp[rc.LP_LZ] = conditions.sky_zenith_cd_m2
        lp[rc.LP_E_SKY] = conditions.sky_illuminance_lux
        lp[rc.LP_SKY_RGB:rc.LP_SKY_RGB + 3] = _rgb_norm([0.97, 1.0, 1.06] if conditions.overcast else [0.78, 0.97, 1.4])
        lp[rc.LP_SUN_DISK_L] = conditions.sun_illuminance_lux / SUN_DISK_SOLID_ANGLE_SR
        lp[rc.LP_SUN_COS] = math.cos(math.radians(0.2665))
        if conditions.sky in clear_sky.CIE_TYPES:
            lp[rc.LP_SKY_KIND] = 1.0
            lp[rc.LP_SKY_ABCDE:rc.LP_SKY_ABCDE + 5] = clear_sky.CIE_TYPES[conditions.sky]
            zs = math.acos(max(-1.0, min(1.0, float(conditions.sun_direction[2]))))
            lp[rc.LP_SKY_NORM] = clear_sky.normaliser(conditions.sky, zs)
        self.hdri = np.zeros((1, 1, 3), np.float32)
        if conditions.hdri is not None:
            img, scale, e_sky = hdri_for(conditions.hdri)
            self.hdri = img
            lp[rc.LP_HDRI], lp[rc.LP_HDRI_SCALE] = 1.0, scale
            lp[rc.LP_HDRI_AZ] = math.radians(float(conditions.hdri.get("azimuth_deg", 0.0)))
            lp[rc.LP_E_SKY] = e_sky
        light = cfg["lighting"]
        lp[rc.LP_E_LAMP_NOM] = 0.0 if not cfg["tunnels"] else float(np.mean(self._e_nom))
        lp[rc.LP_DAYLIGHT_MODEL] = 1.0 if light["daylight_model"] == "portal_view_factor" else 0.0
        self.lp = lp  # the portal views below render with this lighting
        self.portal_lum, l20 = self._portal_lighting(conditions, lp)
        albedo_road = float(cfg["albedo"]["road"])
        e_glob = lp[rc.LP_E_SKY] + lp[rc.LP_E_SUN] * max(lp[2], 0.0)
        # CIE 88 L20 per tunnel: the 20° cone (portal_views.access_luminance_l20), or (old runs) the sunlit/daylit
        # road ahead alone
        l_road = albedo_road * e_glob / math.pi
        self.l20_cd_m2 = l20 if l20 is not None else np.full(len(self._lamp_count), l_road)
        spacing = float(cfg["lamps"]["spacing_m"])
        mult = np.ones((len(self._lamp_count), int(self._lamp_count.max())))
        k, l_th, l_tr = float(light["threshold_k"]), float(light["threshold_length_m"]), float(light["transition_length_m"])
        for ti, n in enumerate(self._lamp_count):
            l_access = float(self.l20_cd_m2[ti])
            l_nom = albedo_road * self._e_nom[ti] * (1 + float(light["interreflection"])) / math.pi
            for j in range(n):
                x = 0.5 * spacing + j * spacing
                if x < 0.5 * l_th:
                    target = k * l_access
                elif x < l_th:  # second half of the threshold zone: linear to 0.4·k·L20
                    target = k * l_access * (1 - 0.6 * (x - 0.5 * l_th) / (0.5 * l_th))
                elif x < l_th + l_tr:  # transition zone, CIE 88 curve at a 60 km/h design speed
                    target = 0.4 * k * l_access * ((1.9 + (x - l_th) / 16.7) / 1.9) ** -1.4
                else:
                    target = 0.0
                mult[ti, j] = max(1.0, target / max(l_nom, 1e-9))
        self.lamp_mult = mult
        self.conditions = conditions
        self._cache.clear()

    def _portal_lighting(self, conditions: Conditions, lp: np.ndarray):
        """(portal_lum (n_tunnels, 2, 2) cd/m², L20 per tunnel or None for the road-only L20) for these conditions,
        from small renders at each tunnel (portal_views), cached per conditions: a traversal's frames share them."""
        light = self.city.cfg["lighting"]
        view_factor = light["daylight_model"] == "portal_view_factor"
        cone = light["l20_method"] == "cone_20deg"
        n_tun = len(self._lamp_count)
        if not self.city.cfg["tunnels"] or not (view_factor or cone):
            return np.zeros((n_tun, 2, 2)), None
        key = (tuple(float(v) for v in conditions.sun_direction), float(conditions.sun_illuminance_lux),
               float(conditions.sky_zenith_cd_m2), bool(conditions.overcast), conditions.sky,
               repr(sorted(conditions.hdri.items())) if conditions.hdri else None)
        if key not in self._lighting_cache:
            if len(self._lighting_cache) > 16:
                self._lighting_cache.clear()
            lum = portal_views.portal_luminances(self, lp) if view_factor else np.zeros((n_tun, 2, 2))
            l20 = (portal_views.access_luminance_l20(self, lp, lum, float(light["l20_stopping_distance_m"]))
                   if cone else None)
            self._lighting_cache[key] = (lum, l20)
        return self._lighting_cache[key]

    # ------------------------------------------------------------------ rendering
    def locate(self, position: np.ndarray):
        """Segment containing a world position and whether it is inside a tunnel's interior."""
        seg = self.seg
        d = position[None, :] - seg[:, rt.P0:rt.P0 + 3]
        in_start = np.einsum("ij,ij->i", d, seg[:, rt.NS:rt.NS + 3]) >= -1e-9
        in_end = np.einsum("ij,ij->i", position[None, :] - seg[:, rt.P1:rt.P1 + 3], seg[:, rt.NE:rt.NE + 3]) <= 1e-9
        v = np.einsum("ij,ij->i", d, seg[:, rt.R:rt.R + 3])
        w = np.einsum("ij,ij->i", d, seg[:, rt.U:rt.U + 3])
        ok = in_start & in_end & (np.abs(v) < seg[:, rt.VMAX])
        if not ok.any():
            raise ValueError("camera position is outside the modelled corridor of the route")
        cand = np.flatnonzero(ok)
        i = int(cand[np.argmin(np.abs(v[cand]) + 10 * np.abs(w[cand]))])
        inside = bool(seg[i, rt.KIND] == rt.KIND_TUNNEL and rc.inside_profile(seg, i, float(v[i]), float(w[i])))
        return i, inside

    def render_full(self, pose: np.ndarray, glare: bool = True) -> dict:
        """Everything the kernel produces: luminance (H, W, 3) cd/m², depth (H, W) m (z-depth; inf for sky),
        code (surface kind, raycast.SKY…FAR), material (index into cities.MATERIALS; 255 sky, 254 lamp)."""
        pose = np.asarray(pose, dtype=np.float64)
        i0, inside = self.locate(pose[:3, 3])
        lum = np.empty((self.height, self.width, 3), np.float32)
        depth = np.empty((self.height, self.width), np.float32)
        code = np.empty((self.height, self.width), np.uint8)
        mat = np.empty((self.height, self.width), np.uint8)
        K = self.K
        render_kernel(self.seg, self.lp, self.texels, self.offs, self.sizes, self.scales, self.albedo,
                      self.lamp_mult, self._lamp_count, self.portal_lum, self.light_map, self.hdri,
                      np.ascontiguousarray(pose[:3, 3]),
                      np.ascontiguousarray(pose[:3, :3]), K[0, 0], K[1, 1], K[0, 2], K[1, 2], i0, inside,
                      lum, depth, code, mat, self.cull)
        if glare:
            lum = self.apply_glare(lum)
        return {"luminance": lum, "depth": depth, "code": code, "material": mat}

    def render(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(luminance_cd_m2 (H, W, 3) float32 incl. veiling glare, depth_m (H, W) float32 z-depth, inf for sky)."""
        out = self.render_full(pose)
        return out["luminance"], out["depth"]

    def apply_glare(self, lum: np.ndarray) -> np.ndarray:
        """Veiling glare: a fraction g of the image luminance is spread by a wide halo (two Gaussians, 2° and 10°)."""
        g = self.glare_fraction
        if g <= 0:
            return lum
        f = self.K[0, 0]
        small = cv2.resize(lum, (max(1, self.width // 8), max(1, self.height // 8)), interpolation=cv2.INTER_AREA)
        halo = np.zeros_like(small)
        for sigma_deg in (2.0, 10.0):
            sigma = max(0.5, f * math.radians(sigma_deg) / 8.0)
            halo += 0.5 * cv2.GaussianBlur(small, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
        halo = cv2.resize(halo, (self.width, self.height), interpolation=cv2.INTER_LINEAR)
        return ((1.0 - g) * lum + g * halo).astype(np.float32)

    @staticmethod
    def _offset_pose(pose, camera_offset_m):
        if camera_offset_m == 0.0:
            return pose
        p = pose.copy()
        p[:3, 3] = pose[:3, 3] + pose[:3, 0] * camera_offset_m
        return p

    def render_exposure(self, trajectory: Trajectory, frame_index: int, exposure_us: float,
                        camera_offset_m: float = 0.0, method: str | None = None) -> np.ndarray:
        """Luminance (cd/m², incl. glare) averaged over the exposure [t_k, t_k + exposure] of frame k, for the camera
        shifted `camera_offset_m` along its x axis (camera 2 of the rig: +0.0392 m)."""
        if trajectory.conditions is not self.conditions:
            self.set_conditions(trajectory.conditions)
        method = method or self.blur
        t0 = float(trajectory.timestamps_ns[frame_index]) * 1e-9
        dur = float(exposure_us) * 1e-6
        if method == "reference":
            n = self._n_subframes(trajectory, t0, dur, camera_offset_m)
            acc = np.zeros((self.height, self.width, 3), np.float64)
            for k in range(n):
                pose = self._offset_pose(trajectory.pose_at(t0 + (k + 0.5) * dur / n), camera_offset_m)
                acc += self.render_full(pose, glare=False)["luminance"]
            return self.apply_glare((acc / n).astype(np.float32))
        # Render once at mid-exposure and smear each pixel along its flow to the exposure's start and end poses.
        # With share_render (optional) one sharp render per frame serves both cameras and every exposure: it is
        # taken at camera 1's frame-start pose whoever asks first (so a frame never depends on the order of the
        # requests), and the flow from there to this camera's start/end poses also carries the 3.92 cm stereo
        # parallax. The start pose keeps the shortest exposures (the sharp images) unresampled.
        key = (trajectory.uid, frame_index) if self.share_render else (
            trajectory.uid, frame_index, float(camera_offset_m), float(exposure_us))
        if key not in self._cache:
            if len(self._cache) > 8:
                self._cache.clear()
            ref = (trajectory.pose_at(t0) if self.share_render
                   else self._offset_pose(trajectory.pose_at(t0 + 0.5 * dur), camera_offset_m))
            self._cache[key] = dict(self.render_full(ref, glare=False), pose=ref)
            self.n_sharp_renders += 1
        sharp = self._cache[key]
        pa = self._offset_pose(trajectory.pose_at(t0), camera_offset_m)
        pb = self._offset_pose(trajectory.pose_at(t0 + dur), camera_offset_m)
        out, max_shift = self._smear(sharp, pa, pb)
        if max_shift < 0.5:  # no visible motion: the sharp render, untouched by resampling
            return self.apply_glare(sharp["luminance"])
        return self.apply_glare(out)

    def _smear(self, sharp: dict, pose_a: np.ndarray, pose_b: np.ndarray) -> tuple[np.ndarray, float]:
        """(luminance smeared along the flow to poses a and b, largest flow component in px); see _blur_kernel.
        When no flow component reaches 0.5 px the caller discards the smear, so it is not computed: (the sharp
        luminance, 0.0). _flow_reaches decides that from the same flows, searched from the bottom row up, where the
        near road moves most, and stops at the first that reaches 0.5 px: a moving frame costs a few rows of flows
        more, a still one (short exposures) the flows without the taps."""
        K = self.K
        args = (sharp["depth"], K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.ascontiguousarray(sharp["pose"]),
                np.ascontiguousarray(pose_a), np.ascontiguousarray(pose_b))
        if not _flow_reaches(*args, 0.5):
            return sharp["luminance"], 0.0
        out = np.empty_like(sharp["luminance"])
        max_shift = _blur_kernel(np.ascontiguousarray(sharp["luminance"]), *args, out)
        return out, max_shift

    def _flow(self, depth, pose_ref, pose_a, pose_b):
        """Pixel displacement (H, W, 2) of each rendered point from the reference pose to poses a and b."""
        K = self.K
        h, w = depth.shape
        xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        z = np.where(np.isfinite(depth), depth, 1.0e5).astype(np.float64)
        pc = np.stack([(xs - K[0, 2]) / K[0, 0] * z, (ys - K[1, 2]) / K[1, 1] * z, z], axis=-1)
        pw = pc @ pose_ref[:3, :3].T + pose_ref[:3, 3]
        res = []
        for pose in (pose_a, pose_b):
            q = (pw - pose[:3, 3]) @ pose[:3, :3]
            zq = np.maximum(q[..., 2], 1e-3)
            res.append(np.stack([K[0, 0] * q[..., 0] / zq + K[0, 2] - xs, K[1, 1] * q[..., 1] / zq + K[1, 2] - ys],
                                axis=-1))
        return res

    def _n_subframes(self, trajectory, t0, dur, camera_offset_m):
        """Sub-frames so that consecutive ones move < 0.5 px (from a coarse render's flow)."""
        coarse = Renderer.__new__(Renderer)
        coarse.__dict__.update(self.__dict__)
        coarse.width, coarse.height = max(8, self.width // 8), max(6, self.height // 8)
        coarse.K = intrinsics(coarse.width, coarse.height, self.hfov_deg)
        p0 = self._offset_pose(trajectory.pose_at(t0), camera_offset_m)
        p1 = self._offset_pose(trajectory.pose_at(t0 + dur), camera_offset_m)
        depth = coarse.render_full(p0, glare=False)["depth"]
        fa, fb = coarse._flow(depth, p0, p0, p1)
        max_flow = float(np.max(np.hypot(*(fb - fa).transpose(2, 0, 1)))) * self.width / coarse.width
        return int(min(self.max_subframes, max(1, math.ceil(2 * max_flow))))


@njit(cache=True, inline="always")
def _project(pose, x, y, z, fx, fy, cx, cy):
    """World point → pixel (x, y) in the camera at `pose` (camera-to-world 4×4)."""
    dx, dy, dz = x - pose[0, 3], y - pose[1, 3], z - pose[2, 3]
    qx = pose[0, 0] * dx + pose[1, 0] * dy + pose[2, 0] * dz
    qy = pose[0, 1] * dx + pose[1, 1] * dy + pose[2, 1] * dz
    qz = max(pose[0, 2] * dx + pose[1, 2] * dy + pose[2, 2] * dz, 1e-3)
    return fx * qx / qz + cx, fy * qy / qz + cy


@njit(cache=True, inline="always")
def _pixel_flows(depth, col, row, x, y, fx, fy, cx, cy, pose_ref, pose_a, pose_b):
    """Flow (fax, fay, fbx, fby) of pixel (x, y) from the reference render to poses a and b (_blur_kernel's)."""
    z = depth[y, x]
    if not z < 1e5:
        z = 1e5
    px = col[x] * z
    py = row[y] * z
    wx = pose_ref[0, 0] * px + pose_ref[0, 1] * py + pose_ref[0, 2] * z + pose_ref[0, 3]
    wy = pose_ref[1, 0] * px + pose_ref[1, 1] * py + pose_ref[1, 2] * z + pose_ref[1, 3]
    wz = pose_ref[2, 0] * px + pose_ref[2, 1] * py + pose_ref[2, 2] * z + pose_ref[2, 3]
    ax, ay = _project(pose_a, wx, wy, wz, fx, fy, cx, cy)
    bx, by = _project(pose_b, wx, wy, wz, fx, fy, cx, cy)
    return ax - (x + 0.5), ay - (y + 0.5), bx - (x + 0.5), by - (y + 0.5)


@njit(cache=True, inline="always")
def _flow_factors(w, h, fx, fy, cx, cy):
    """Per column / row factors of the back-projection: the same divisions as per pixel, done once."""
    col = np.empty(w)
    for x in range(w):
        col[x] = (x + 0.5 - cx) / fx
    row = np.empty(h)
    for y in range(h):
        row[y] = (y + 0.5 - cy) / fy
    return col, row


@njit(cache=True)
def _flow_reaches(depth, fx, fy, cx, cy, pose_ref, pose_a, pose_b, limit):
    """Whether any flow component of _blur_kernel reaches `limit` px (its returned maximum ≥ limit), rows from the
    bottom up (one thread: a moving frame stops within the first rows)."""
    h, w = depth.shape
    col, row = _flow_factors(w, h, fx, fy, cx, cy)
    for y in range(h - 1, -1, -1):
        for x in range(w):
            fax, fay, fbx, fby = _pixel_flows(depth, col, row, x, y, fx, fy, cx, cy, pose_ref, pose_a, pose_b)
            if max(abs(fax), abs(fay), abs(fbx), abs(fby)) >= limit:
                return True
    return False


@njit(cache=True, parallel=True)
def _blur_kernel(img, depth, fx, fy, cx, cy, pose_ref, pose_a, pose_b, out):
    """Exposure average by smearing: pixel x at time τ ∈ [start, end] sees the rendered point that sat at
    x − flow(τ), flow interpolated linearly between the flows to the start (a) and end (b) poses, evaluated at x
    from the reference render's depth (sky at 100 km). Samples per pixel follow its own blur length (≤ 64).
    Returns the largest flow magnitude (px)."""
    h, w = depth.shape
    row_max = np.zeros(h)
    stride = rc.spread_stride(h)
    # per column / row factors of the back-projection and the tap positions along the blur line: the same divisions
    # as per pixel / per tap before, done once (bit-identical)
    col, row = _flow_factors(w, h, fx, fy, cx, cy)
    frac = np.empty((65, 64))
    for n in range(1, 65):
        for k in range(n):
            frac[n, k] = (k + 0.5) / n
    flat = img.reshape(h * w * 3)  # taps index the flat image: one index per load instead of three (same values)
    for ky in prange(h):
        y = (ky * stride) % h  # blur lengths grow toward the bottom rows: spread each thread's rows (spread_stride)
        m = 0.0
        for x in range(w):
            fax, fay, fbx, fby = _pixel_flows(depth, col, row, x, y, fx, fy, cx, cy, pose_ref, pose_a, pose_b)
            m = max(m, abs(fax), abs(fay), abs(fbx), abs(fby))
            length = math.sqrt((fbx - fax) ** 2 + (fby - fay) ** 2)
            n = min(64, int(math.ceil(2.0 * length)) + 1) if length >= 0.5 else 1
            acc0 = 0.0
            acc1 = 0.0
            acc2 = 0.0
            for k in range(n):
                a = frac[n, k]
                sx = min(max(x - ((1 - a) * fax + a * fbx), 0.0), w - 1.0)
                sy = min(max(y - ((1 - a) * fay + a * fby), 0.0), h - 1.0)
                x0 = int(sx)
                y0 = int(sy)
                x1 = min(x0 + 1, w - 1)
                y1 = min(y0 + 1, h - 1)
                ux = sx - x0
                uy = sy - y0
                w00 = (1 - ux) * (1 - uy)
                w01 = ux * (1 - uy)
                w10 = (1 - ux) * uy
                w11 = ux * uy
                i00 = (y0 * w + x0) * 3
                i01 = (y0 * w + x1) * 3
                i10 = (y1 * w + x0) * 3
                i11 = (y1 * w + x1) * 3
                acc0 += w00 * flat[i00] + w01 * flat[i01] + w10 * flat[i10] + w11 * flat[i11]
                acc1 += w00 * flat[i00 + 1] + w01 * flat[i01 + 1] + w10 * flat[i10 + 1] + w11 * flat[i11 + 1]
                acc2 += w00 * flat[i00 + 2] + w01 * flat[i01 + 2] + w10 * flat[i10 + 2] + w11 * flat[i11 + 2]
            out[y, x, 0] = acc0 / n
            out[y, x, 1] = acc1 / n
            out[y, x, 2] = acc2 / n
        row_max[y] = m
    return row_max.max()
