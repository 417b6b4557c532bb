"""Per-pixel render kernel: primary ray → hit → albedo (textures, markings) → illumination → luminance (cd/m²)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from expoctl.world import raycast as rc
from expoctl.world import route as rt
from expoctl.world.clear_sky import general_sky_inline
from expoctl.world.daylight import LM_CEIL, LM_ROAD, LM_WALL, light_map_factors, opening_factors_inline

MAT_SKY, MAT_LAMP = 255, 254


@njit(cache=True, inline="always")
def _sky(lp, hdri, dx, dy, dz, out):
    if lp[rc.LP_HDRI] > 0.5:
        h, w = hdri.shape[0], hdri.shape[1]
        az = math.atan2(dy, dx) + lp[rc.LP_HDRI_AZ]
        el = math.asin(max(-1.0, min(1.0, dz)))
        x = ((0.5 - az / (2 * math.pi)) % 1.0) * w - 0.5
        y = (0.5 - el / math.pi) * h - 0.5
        x0 = int(math.floor(x))
        y0 = min(max(int(math.floor(y)), 0), h - 1)
        y1 = min(y0 + 1, h - 1)
        ax = x - math.floor(x)
        ay = min(max(y - y0, 0.0), 1.0)
        xa, xb = x0 % w, (x0 + 1) % w
        k = lp[rc.LP_HDRI_SCALE]
        for c in range(3):
            v = (hdri[y0, xa, c] * (1 - ax) + hdri[y0, xb, c] * ax) * (1 - ay) + (
                hdri[y1, xa, c] * (1 - ax) + hdri[y1, xb, c] * ax) * ay
            out[c] = k * v
        return
    cs = dx * lp[0] + dy * lp[1] + dz * lp[2]
    if lp[rc.LP_SKY_KIND] > 0.5:
        # CIE general (clear) sky around the sun; below the horizon the horizon value (clear_sky.general_sky_inline)
        k = rc.LP_SKY_ABCDE
        lum = lp[rc.LP_LZ] * general_sky_inline(lp[k], lp[k + 1], lp[k + 2], lp[k + 3], lp[k + 4], lp[rc.LP_SKY_NORM],
                                                dz, cs)
    else:
        # CIE standard overcast sky: L(θ) = Lz (1 + 2 cos θ) / 3 (θ from zenith); below the horizon the horizon value
        lum = lp[rc.LP_LZ] * (1.0 + 2.0 * max(dz, 0.0)) / 3.0
    for c in range(3):
        out[c] = lum * lp[rc.LP_SKY_RGB + c]
    if lp[rc.LP_E_SUN] > 0.0 and cs > lp[rc.LP_SUN_COS]:
        for c in range(3):
            out[c] += lp[rc.LP_SUN_DISK_L]


@njit(cache=True, inline="always")
def _lamp_height(seg, j, v):
    if seg[j, rt.ARC_R] == 0.0:
        return seg[j, rt.CROWN_H] - 0.05
    dv = min(abs(v), seg[j, rt.ARC_R] * 0.95)
    return seg[j, rt.ARC_C] + math.sqrt(seg[j, rt.ARC_R] ** 2 - dv * dv) - 0.05


@njit(cache=True, inline="always")
def _lamp_illuminance(seg, j, lp, lamp_mult, lamp_count, x, u, v, w, nu, nv, nw):
    """Illuminance (lux, lamp colour) at tunnel point (x along the tunnel; u, v, w in segment j) from nearby lamps."""
    tid = int(seg[j, rt.TUN_ID])
    spacing = lp[rc.LP_LAMP_SPACING]
    area = lp[rc.LP_LAMP_LEN] * lp[rc.LP_LAMP_W]
    intensity = lp[rc.LP_LAMP_L] * area  # cd along the panel normal (straight down)
    kc = int(math.floor((x - 0.5 * spacing) / spacing + 0.5))
    n_rows = int(lp[rc.LP_N_ROWS])
    # the panel height of each row depends only on the row and the segment: once per pixel, not once per lamp
    # (the arch profile needs a square root); up to 4 rows (LP_ROWS holds 4 slots)
    hr0 = _lamp_height(seg, j, lp[rc.LP_ROWS]) if n_rows > 0 else 0.0
    hr1 = _lamp_height(seg, j, lp[rc.LP_ROWS + 1]) if n_rows > 1 else 0.0
    hr2 = _lamp_height(seg, j, lp[rc.LP_ROWS + 2]) if n_rows > 2 else 0.0
    hr3 = _lamp_height(seg, j, lp[rc.LP_ROWS + 3]) if n_rows > 3 else 0.0
    heights = (hr0, hr1, hr2, hr3)
    e = 0.0
    for k in range(kc - 4, kc + 5):
        if k < 0 or k >= lamp_count[tid]:
            continue
        du = (0.5 * spacing + k * spacing) - x
        for r in range(n_rows):
            vr = lp[rc.LP_ROWS + r]
            ddv = vr - v
            ddw = heights[r] - w
            # the signs of both cosines are known before the square root and the divisions: skip lamps behind the
            # panel or the surface (every lamp for the ceiling, the far row for walls), which add nothing anyway
            if not (ddw > 0.0 and nu * du + nv * ddv + nw * ddw > 0.0):
                continue
            r2 = du * du + ddv * ddv + ddw * ddw
            rr = math.sqrt(r2)
            cos_l = ddw / rr
            cos_s = (nu * du + nv * ddv + nw * ddw) / rr
            if cos_l > 0.0 and cos_s > 0.0:
                e += lamp_mult[tid, k] * intensity * cos_l * cos_s / max(r2, area)
    return e


@njit(cache=True, inline="always")
def _road_marking(lp, s, v, half_v, half_s):
    """Coverage (0..1) of white paint: solid edge lines, dashed lane dividers (3 m of paint every 12 m)."""
    lanes = int(lp[rc.LP_LANES])
    lw = lp[rc.LP_LANE_W]
    edge = lanes * lw / 2.0
    cov = _box_cover(v, half_v, -edge + 0.1, 0.075) + _box_cover(v, half_v, edge - 0.1, 0.075)
    for k in range(1, lanes):
        across = _box_cover(v, half_v, -edge + k * lw, 0.07)
        if across > 0.0:
            cov += across * rc.dash_cover(s, half_s, 12.0, 3.0, 0.0)
    return min(cov, 1.0)


_box_cover = rc.box_cover


# inlined into the parallel pixel loop: a call passed ~110 scalars (every array as ~9) per pixel; inlining it and
# its helpers made the whole kernel ~1.3× faster (measured, 320×240, one thread)
@njit(cache=True, inline="always")
def shade_pixel(seg, lp, texels, offs, sizes, scales, albedo, lamp_mult, lamp_count, portal_lum, light_map, hdri,
                ox, oy, oz, dx, dy, dz, pix_rad, start_seg, start_inside, out, tex, cull):
    """Luminance of one ray into out[0:3]; returns (t, code, material).
    seg: a raycast.with_frame_terms table for the camera position (ox, oy, oz) and the sun direction (lp[0:3]).
    portal_lum: (n_tunnels, 2, 2) mean luminance (cd/m², Y) seen out of each tunnel's start and end openings, looking
    up and looking down (portal_views.portal_luminances).
    light_map: daylight.light_map's per-tunnel table of the portals' configuration factors (opt-in), or
    daylight.NO_LIGHT_MAP (no rows): the exact integral per pixel."""
    t, code, j, air, air_in, u, v, w, nu, nv, nw, mat = rc.trace(
        seg, start_seg, start_inside, ox, oy, oz, dx, dy, dz, lp[rc.LP_TMAX], lp[rc.LP_ZTOP], cull,
        True, False, False)
    if code == rc.SKY:
        _sky(lp, hdri, dx, dy, dz, out)
        return rc.INF, code, MAT_SKY
    texel_m = lp[rc.LP_TEXEL_M]
    if code == rc.FAR:
        # beyond the modelled corridor: distant ground at the verge's mean albedo, unshadowed daylight
        e = lp[rc.LP_E_SKY] + lp[rc.LP_E_SUN] * max(lp[2], 0.0)
        for c in range(3):
            out[c] = albedo[rc.MAT_VERGE] * e / math.pi
        return 1.0e4, code, rc.MAT_VERGE
    nx = nu * seg[j, rt.F] + nv * seg[j, rt.R] + nw * seg[j, rt.U]
    ny = nu * seg[j, rt.F + 1] + nv * seg[j, rt.R + 1] + nw * seg[j, rt.U + 1]
    nz = nu * seg[j, rt.F + 2] + nv * seg[j, rt.R + 2] + nw * seg[j, rt.U + 2]
    s_hit = seg[j, rt.S0] + u
    interior = seg[j, rt.KIND] == rt.KIND_TUNNEL and (code == rc.GROUND or code == rc.TWALL or code == rc.TCEIL)
    road_half = lp[rc.LP_ROAD_HALF]
    if code == rc.GROUND:
        a, b = s_hit, v
        av = abs(v)
        if av < road_half:
            mat = rc.MAT_ROAD
        elif interior or av < road_half + lp[rc.LP_SIDEWALK]:
            mat = rc.MAT_SIDEWALK
        else:
            mat = rc.MAT_VERGE
    elif code == rc.SIDE or code == rc.TWALL:
        a, b = s_hit, w
    elif code == rc.FACE:
        a, b = v + 37.0 * seg[j, rt.S0], w
    elif code == rc.PROP:
        if abs(nu) > 0.5:
            a, b = v + 37.0 * seg[j, rt.S0], w
        elif abs(nv) > 0.5:
            a, b = s_hit, w
        else:
            a, b = s_hit, v
    else:
        a, b = s_hit, v
    cos_i = abs(nx * dx + ny * dy + nz * dz)
    foot_across = t * pix_rad
    foot = foot_across / math.sqrt(max(cos_i, 0.02))  # geometric mean of the footprint's two axes
    rc.sample_texture(texels, offs, sizes, scales, mat, a, b, foot * lp[rc.LP_MIP_BIAS], texel_m, tex)
    alb = albedo[mat]
    if mat == rc.MAT_ROAD:
        paint = _road_marking(lp, s_hit, v, max(0.5 * foot, 1e-4), max(0.5 * foot_across / max(cos_i, 0.02), 1e-4))
        for c in range(3):
            tex[c] = (1.0 - paint) * tex[c] * alb + paint * 0.6
    else:
        for c in range(3):
            tex[c] *= alb
    # illumination
    e_day = 0.0
    e_lamp = 0.0
    sun_x, sun_y, sun_z = lp[0], lp[1], lp[2]
    e_sun = lp[rc.LP_E_SUN]
    cos_sun = nx * sun_x + ny * sun_y + nz * sun_z
    if e_sun > 0.0 and cos_sun > 0.0 and sun_z > 0.0:
        px, py, pz = ox + t * dx + 0.02 * nx, oy + t * dy + 0.02 * ny, oz + t * dz + 0.02 * nz
        # only whether the sun is blocked matters: the first hit found ends the walk (any_hit)
        ts = rc.trace(seg, air, air_in, px, py, pz, sun_x, sun_y, sun_z, lp[rc.LP_TMAX], lp[rc.LP_ZTOP], cull,
                      False, True, True)[1]
        if ts == rc.SKY:
            e_day += e_sun * cos_sun
    if not interior:
        e_day += lp[rc.LP_E_SKY] * 0.5 * (1.0 + nz)
    else:
        x = s_hit - seg[j, rt.TUN_S0]
        tl = seg[j, rt.TUN_LEN]
        tid = int(seg[j, rt.TUN_ID])
        if lp[rc.LP_DAYLIGHT_MODEL] > 0.5:
            # diffuse daylight through both openings (the sun's own patch is the shadow ray's, above): the parts
            # above and below the point's height each with the luminance seen out of the portal upward / downward
            if light_map.shape[0] > 0:
                surf = LM_ROAD if code == rc.GROUND else (LM_WALL if code == rc.TWALL else LM_CEIL)
                f0, f1, g0, g1 = light_map_factors(light_map, tid, surf, seg[j, rt.HW], seg[j, rt.WALL_H],
                                                   seg[j, rt.CROWN_H], seg[j, rt.ARC_C], seg[j, rt.ARC_R], tl, x, v,
                                                   w, nv, nw)
            else:
                f0, f1, g0, g1 = opening_factors_inline(seg[j, rt.HW], seg[j, rt.WALL_H], seg[j, rt.CROWN_H],
                                                        seg[j, rt.ARC_C], seg[j, rt.ARC_R], x, tl - x, v, w, nv, nw)
            e_day += math.pi * ((f0 - g0) * portal_lum[tid, 0, 0] + g0 * portal_lum[tid, 0, 1]
                                + (f1 - g1) * portal_lum[tid, 1, 0] + g1 * portal_lum[tid, 1, 1])
        else:
            tail = lp[rc.LP_TAIL_M]
            e_glob = lp[rc.LP_E_SKY] + e_sun * max(sun_z, 0.0)
            e_day += lp[rc.LP_TAIL_FRAC] * e_glob * (math.exp(-3.0 * x / tail) + math.exp(-3.0 * (tl - x) / tail))
        e_lamp += _lamp_illuminance(seg, j, lp, lamp_mult, lamp_count, x, u, v, w, nu, nv, nw)
        spacing = lp[rc.LP_LAMP_SPACING]
        kc = min(max(int(math.floor((x - 0.5 * spacing) / spacing + 0.5)), 0), lamp_count[tid] - 1)
        e_lamp += lp[rc.LP_INTERREFL] * lp[rc.LP_E_LAMP_NOM] * lamp_mult[tid, kc]
    for c in range(3):
        out[c] = tex[c] * (e_day + e_lamp * lp[rc.LP_LAMP_RGB + c]) / math.pi
    if code == rc.TCEIL:
        # emissive lamp panels, box-filtered over the pixel footprint
        x = s_hit - seg[j, rt.TUN_S0]
        spacing = lp[rc.LP_LAMP_SPACING]
        half = max(0.5 * foot, 1e-4)
        along = rc.dash_cover(x, half, spacing, lp[rc.LP_LAMP_LEN], 0.5 * spacing - 0.5 * lp[rc.LP_LAMP_LEN])
        if x < 0.0 or x > seg[j, rt.TUN_LEN]:
            along = 0.0
        if along > 0.0:
            cov = 0.0
            for r in range(int(lp[rc.LP_N_ROWS])):
                cov += _box_cover(v, half, lp[rc.LP_ROWS + r], 0.5 * lp[rc.LP_LAMP_W])
            cov = min(cov * along, 1.0)
            if cov > 0.0:
                tid = int(seg[j, rt.TUN_ID])
                kc = min(max(int(math.floor((x - 0.5 * spacing) / spacing + 0.5)), 0), lamp_count[tid] - 1)
                le = lp[rc.LP_LAMP_L] * lamp_mult[tid, kc]
                for c in range(3):
                    out[c] = (1.0 - cov) * out[c] + cov * le * lp[rc.LP_LAMP_RGB + c]
                if cov > 0.5:
                    mat = MAT_LAMP
    return t, code, mat


@njit(cache=True, parallel=True)
def render_kernel(seg, lp, texels, offs, sizes, scales, albedo, lamp_mult, lamp_count, portal_lum, light_map, hdri,
                  cam, rot, fx, fy, cx, cy, start_seg, start_inside, out_l, out_depth, out_code, out_mat, cull):
    """Render every pixel. rot: camera-to-world rotation (columns = camera x right, y down, z forward).
    cull: cheap reach test before each block/prop intersection (raycast.trace); False = exact test for all."""
    h, w = out_depth.shape
    pix_rad = 1.0 / fx
    stride = rc.spread_stride(h)
    # per-segment terms shared by every primary ray (camera origin) and every shadow ray (sun direction)
    segf = rc.with_frame_terms(seg, cam[0], cam[1], cam[2], lp[0], lp[1], lp[2])
    # the camera-frame ray slopes per column and per row: the same divisions as per pixel, done once (bit-identical)
    cxrs = np.empty(w)
    for xx in range(w):
        cxrs[xx] = (xx + 0.5 - cx) / fx
    for k in prange(h):
        yy = (k * stride) % h  # spread each thread's share of rows over the image (see spread_stride)
        px = np.empty(3)
        tex = np.empty(3)
        cyr = (yy + 0.5 - cy) / fy
        for xx in range(w):
            cxr = cxrs[xx]
            nrm = 1.0 / math.sqrt(cxr * cxr + cyr * cyr + 1.0)
            dx = (rot[0, 0] * cxr + rot[0, 1] * cyr + rot[0, 2]) * nrm
            dy = (rot[1, 0] * cxr + rot[1, 1] * cyr + rot[1, 2]) * nrm
            dz = (rot[2, 0] * cxr + rot[2, 1] * cyr + rot[2, 2]) * nrm
            # a pixel's angular size shrinks off-axis (cos² radially, cos tangentially): use cos^1.5 ≈ nrm·sqrt(nrm)
            t, code, mat = shade_pixel(segf, lp, texels, offs, sizes, scales, albedo, lamp_mult, lamp_count,
                                       portal_lum, light_map, hdri,
                                       cam[0], cam[1], cam[2], dx, dy, dz, pix_rad * nrm * math.sqrt(nrm), start_seg,
                                       start_inside, px, tex, cull)
            out_l[yy, xx, 0] = px[0]
            out_l[yy, xx, 1] = px[1]
            out_l[yy, xx, 2] = px[2]
            out_depth[yy, xx] = t * nrm if t < 1.0e29 else np.inf
            out_code[yy, xx] = code
            out_mat[yy, xx] = mat
