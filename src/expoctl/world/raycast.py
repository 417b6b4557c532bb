"""Numba ray caster: per pixel, walk the segment table, find the first surface, shade it in absolute luminance.

Shading is Lambertian: L = albedo · E / π per RGB channel (cd/m²; E in lux), with E from
- outside: direct sun (n·s, shadow ray through the same walker) + sky diffuse E_sky·(1 + n_z)/2;
- inside a tunnel: the lamps as flat Lambertian panels (I = L_lamp·A·cos θ, inverse-square, cosine at the surface),
  daylight through each portal opening, π·L_opening·F (F: the opening's configuration factor from the surface point,
  expoctl.world.daylight; or, for old runs, a tail frac·E_global·exp(−3x/tail_m), 5 % left at tail_m),
  an interreflection ambient, and direct sun where the shadow ray leaves through a portal.
Emitters: lamp panels (box-filtered coverage, so sub-pixel lamps do not flicker), sky (CIE overcast, CIE general
clear sky or HDRI), sun disk.
Textures are sampled trilinearly from mip pyramids at the level of the projected pixel footprint.

Speed (all bit-identical to the straightforward code): the small per-ray helpers are inlined into their callers
(`inline="always"`, numba IR level) because each call passed every array as ~9 scalars and returned a tuple through
memory; blocks and props the ray cannot reach are rejected before their exact test (trace, `cull`). `trace` itself is
not inlined: it is called twice per pixel, and inlining it quadrupled the compile time for ~5 % of render time.
The per-segment products of a segment step that depend only on the ray origin (primary rays: the camera) or only on
its direction (shadow rays: the sun) are computed once per frame (with_frame_terms) and read by trace.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from expoctl.world import route as rt

SKY, GROUND, SIDE, ROOF, TWALL, TCEIL, FACE, HILLTOP, FAR, PROP = 0, 1, 2, 3, 4, 5, 6, 7, 8, 9
INF = 1.0e30
# Slack (m) of the cheap reach test before a block's or prop's exact intersection test: the end points of the ray
# piece are rounded at ~1e-13 m (coordinates ≲ 1e3 m), so 1 µm never rejects a block or box the exact test would hit.
CULL_MARGIN_M = 1.0e-6

# lighting parameter vector (float64) indices
LP_SUN = 0  # 3: unit vector toward the sun (world)
LP_E_SUN, LP_E_SKY, LP_LZ = 3, 4, 5  # normal sun illuminance, horizontal sky illuminance (lux), sky zenith cd/m²
LP_SKY_RGB = 6  # 3
LP_SUN_DISK_L, LP_SUN_COS = 9, 10  # sun-disk luminance, cos of its angular radius
LP_LAMP_L, LP_LAMP_RGB, LP_LAMP_LEN, LP_LAMP_W, LP_LAMP_SPACING = 11, 12, 15, 16, 17
LP_N_ROWS, LP_ROWS = 18, 19  # up to 4 lamp rows (lateral positions)
LP_TAIL_M, LP_TAIL_FRAC, LP_INTERREFL, LP_E_LAMP_NOM = 23, 24, 25, 26
LP_ROAD_HALF, LP_LANE_W, LP_LANES, LP_SIDEWALK = 27, 28, 29, 30
LP_TEXEL_M, LP_TILE_PX, LP_MIP_BIAS, LP_TMAX, LP_ZTOP = 31, 32, 33, 34, 35
LP_HDRI, LP_HDRI_AZ, LP_HDRI_SCALE = 36, 37, 38
# analytic sky: LP_SKY_KIND 0 = CIE overcast, 1 = CIE general sky with parameters a, b, c, d, e at LP_SKY_ABCDE and
# LP_SKY_NORM = 1 / (f(Zs)·φ(0)) (expoctl.world.clear_sky)
LP_SKY_KIND, LP_SKY_ABCDE, LP_SKY_NORM = 39, 40, 45
# daylight inside tunnels: 0 = exponential tail (LP_TAIL_M, LP_TAIL_FRAC; runs before issue 23), 1 = view factor of
# each portal opening × the luminance seen through it (expoctl.world.daylight; per-portal luminances in portal_lum)
LP_DAYLIGHT_MODEL = 46
LP_N = 47

MAT_ROAD, MAT_SIDEWALK, MAT_VERGE = 0, 1, 2
MAT_TWALL, MAT_TCEIL, MAT_PORTAL, MAT_HILL, MAT_ROOF = 7, 8, 9, 10, 11


@njit(cache=True, inline="always")
def _dot(seg, i, c, x, y, z):
    return x * seg[i, c] + y * seg[i, c + 1] + z * seg[i, c + 2]


@njit(cache=True, inline="always")
def inside_profile(seg, j, v, w):
    hw = seg[j, rt.HW]
    if w <= 0.0 or v <= -hw or v >= hw:
        return False
    if seg[j, rt.ARC_R] == 0.0:
        return w < seg[j, rt.CROWN_H]
    if w <= seg[j, rt.WALL_H]:
        return True
    dc = w - seg[j, rt.ARC_C]
    return v * v + dc * dc < seg[j, rt.ARC_R] ** 2


@njit(cache=True, inline="always")
def _block_entry(o_v, o_w, d_v, d_w, off, h, sign):
    """Entry time of the ray into the solid {sign·v > off, w < h} and whether it enters through the side (True) or the roof."""
    # interval where sign*v > off
    sv, sdv = sign * o_v, sign * d_v
    if sdv > 1e-12:
        lo_v, hi_v = (off - sv) / sdv, INF
    elif sdv < -1e-12:
        lo_v, hi_v = -INF, (off - sv) / sdv
    elif sv > off:
        lo_v, hi_v = -INF, INF
    else:
        return INF, True
    if d_w < -1e-12:
        lo_w, hi_w = (h - o_w) / d_w, INF
    elif d_w > 1e-12:
        lo_w, hi_w = -INF, (h - o_w) / d_w
    elif o_w < h:
        lo_w, hi_w = -INF, INF
    else:
        return INF, True
    entry = max(lo_v, lo_w)
    if entry < min(hi_v, hi_w):
        return entry, lo_v >= lo_w
    return INF, True


@njit(cache=True, inline="always")
def _slab(o, d, lo, hi, tmin, tmax):
    """Clip [tmin, tmax] to the slab lo <= o + t·d <= hi; returns (tmin, tmax, entered_here, entry_sign)."""
    if abs(d) < 1e-12:
        if o < lo or o > hi:
            return 1.0, 0.0, False, 0.0
        return tmin, tmax, False, 0.0
    ta = (lo - o) / d
    tb = (hi - o) / d
    sign = -1.0
    if ta > tb:
        ta, tb = tb, ta
        sign = 1.0
    entered = False
    if ta > tmin:
        tmin = ta
        entered = True
    if tb < tmax:
        tmax = tb
    return tmin, tmax, entered, sign


@njit(cache=True, inline="always")
def _box_hit(seg, i, col, ou, ov, ow, du, dv, dw, t0, best):
    """Entry time into box `col` of segment i (local coords) and its outward normal, or INF."""
    tmin, tmax = t0, best
    nu = nv = nw = 0.0
    tmin, tmax, e, sg = _slab(ou, du, seg[i, col], seg[i, col + 1], tmin, tmax)
    if e:
        nu, nv, nw = sg, 0.0, 0.0
    if tmin > tmax:
        return INF, 0.0, 0.0, 0.0
    tmin, tmax, e, sg = _slab(ov, dv, seg[i, col + 2], seg[i, col + 3], tmin, tmax)
    if e:
        nu, nv, nw = 0.0, sg, 0.0
    if tmin > tmax:
        return INF, 0.0, 0.0, 0.0
    tmin, tmax, e, sg = _slab(ow, dw, seg[i, col + 4], seg[i, col + 5], tmin, tmax)
    if e:
        nu, nv, nw = 0.0, 0.0, sg
    if tmin > tmax or (nu == 0.0 and nv == 0.0 and nw == 0.0):
        return INF, 0.0, 0.0, 0.0
    return tmin, nu, nv, nw


# Columns appended to a per-frame copy of the segment table (with_frame_terms): the products of a segment step that
# depend only on the ray origin (primary rays share the camera's) or only on its direction (shadow rays share the sun's)
T_O = rt.NCOL  # 5: local u, v, w of the origin; numerators of the end / start plane crossing times
T_D = rt.NCOL + 5  # 5: local du, dv, dw of the direction; its dot products with the end / start plane normals
# the segment's highest open-road surface in its own frame (ground 0, roadside blocks, prop boxes; m): a ray piece
# above it and rising in this frame cannot hit anything of the segment (trace's light step)
T_HMAX = rt.NCOL + 10
T_NCOL = rt.NCOL + 11


@njit(cache=True)
def with_frame_terms(seg, ox, oy, oz, dx, dy, dz):
    """The segment table plus, per segment, trace's origin terms for o and direction terms for d (T_O, T_D): the same
    expressions trace evaluates at every segment step, so reading them instead gives bit-identical results. Kept in
    the table itself, not in extra arrays, because trace is a real call and every array argument costs ~9 scalars."""
    n = seg.shape[0]
    out = np.empty((n, T_NCOL))
    out[:, :rt.NCOL] = seg
    for i in range(n):
        h = 0.0
        if seg[i, rt.L_OFF] < rt.NO_BLOCK_OFFSET:
            h = max(h, seg[i, rt.L_H])
        if seg[i, rt.R_OFF] < rt.NO_BLOCK_OFFSET:
            h = max(h, seg[i, rt.R_H])
        for b in range(int(seg[i, rt.N_BOXES])):
            h = max(h, seg[i, rt.BOX0 + rt.BOX_STRIDE * b + 5])
        out[i, T_HMAX] = h
        out[i, T_O] = _dot(seg, i, rt.F, ox - seg[i, 0], oy - seg[i, 1], oz - seg[i, 2])
        out[i, T_O + 1] = _dot(seg, i, rt.R, ox - seg[i, 0], oy - seg[i, 1], oz - seg[i, 2])
        out[i, T_O + 2] = _dot(seg, i, rt.U, ox - seg[i, 0], oy - seg[i, 1], oz - seg[i, 2])
        out[i, T_O + 3] = _dot(seg, i, rt.NE, seg[i, rt.P1] - ox, seg[i, rt.P1 + 1] - oy, seg[i, rt.P1 + 2] - oz)
        out[i, T_O + 4] = _dot(seg, i, rt.NS, seg[i, 0] - ox, seg[i, 1] - oy, seg[i, 2] - oz)
        out[i, T_D] = _dot(seg, i, rt.F, dx, dy, dz)
        out[i, T_D + 1] = _dot(seg, i, rt.R, dx, dy, dz)
        out[i, T_D + 2] = _dot(seg, i, rt.U, dx, dy, dz)
        out[i, T_D + 3] = _dot(seg, i, rt.NE, dx, dy, dz)
        out[i, T_D + 4] = _dot(seg, i, rt.NS, dx, dy, dz)
    return out


@njit(cache=True)
def trace(seg, i0, inside0, ox, oy, oz, dx, dy, dz, tmax, ztop, cull, use_o, use_d, any_hit):
    """First hit along o + t·d. Returns (t, code, frame_seg, air_seg, air_inside, u, v, w, nu, nv, nw, mat).
    cull: reject roadside blocks and props the ray cannot reach before their exact test (same result, faster);
    with cull, an open-road segment whose surfaces all lie below the ray piece (rising in the segment's frame, above
    its highest block or prop, T_HMAX) takes only the walk to the next segment (light step: the same hits, the same
    crossing times, since the walk's arithmetic is untouched).
    any_hit: the caller needs only whether something is hit, not what (shadow rays): return at the first hit found
    in a segment instead of the nearest one. The code is then a hit code (≥ 1, not SKY) exactly when the nearest hit's
    would be; the other outputs are those of the first hit found.
    use_o / use_d: read the origin / direction terms of each segment step from the columns T_O / T_D of seg (a
    with_frame_terms table made for this o / d) instead of recomputing them: every primary ray of a frame shares the
    camera origin and every shadow ray the sun direction (same numbers, fewer multiplications per step)."""
    nseg = seg.shape[0]
    i = i0
    inside = inside0
    t0 = 0.0
    for _ in range(4096):
        if use_o:
            ou, ov, ow = seg[i, T_O], seg[i, T_O + 1], seg[i, T_O + 2]
        else:
            ou = _dot(seg, i, rt.F, ox - seg[i, 0], oy - seg[i, 1], oz - seg[i, 2])
            ov = _dot(seg, i, rt.R, ox - seg[i, 0], oy - seg[i, 1], oz - seg[i, 2])
            ow = _dot(seg, i, rt.U, ox - seg[i, 0], oy - seg[i, 1], oz - seg[i, 2])
        if use_d:
            du, dv, dw = seg[i, T_D], seg[i, T_D + 1], seg[i, T_D + 2]
        else:
            du = _dot(seg, i, rt.F, dx, dy, dz)
            dv = _dot(seg, i, rt.R, dx, dy, dz)
            dw = _dot(seg, i, rt.U, dx, dy, dz)
        # nothing above ztop: a rising ray above it sees only sky
        if dw > 0.0 and ow + t0 * dw > ztop:
            return INF, SKY, i, i, inside, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1
        t_exit = INF
        dirn = 0
        dn = seg[i, T_D + 3] if use_d else _dot(seg, i, rt.NE, dx, dy, dz)
        if dn > 1e-12:
            num = seg[i, T_O + 3] if use_o else _dot(seg, i, rt.NE, seg[i, rt.P1] - ox, seg[i, rt.P1 + 1] - oy,
                                                  seg[i, rt.P1 + 2] - oz)
            te = num / dn
            if te < t_exit:
                t_exit, dirn = max(te, t0), 1
        dn = seg[i, T_D + 4] if use_d else _dot(seg, i, rt.NS, dx, dy, dz)
        if dn < -1e-12:
            num = seg[i, T_O + 4] if use_o else _dot(seg, i, rt.NS, seg[i, 0] - ox, seg[i, 1] - oy, seg[i, 2] - oz)
            ts = num / dn
            if ts < t_exit:
                t_exit, dirn = max(ts, t0), -1
        best = min(t_exit, tmax)
        code = -1
        nu = nv = nw = 0.0
        mat = -1
        if seg[i, rt.KIND] == rt.KIND_TUNNEL and inside:
            hw = seg[i, rt.HW]
            wall_h = seg[i, rt.WALL_H]
            if dw < -1e-12:
                t = -ow / dw
                if t0 <= t < best:
                    best, code, nu, nv, nw, mat = t, GROUND, 0.0, 0.0, 1.0, MAT_ROAD
            if dv > 1e-12:
                t = (hw - ov) / dv
                if t0 <= t < best and ow + t * dw <= wall_h:
                    best, code, nu, nv, nw, mat = t, TWALL, 0.0, -1.0, 0.0, MAT_TWALL
            elif dv < -1e-12:
                t = (-hw - ov) / dv
                if t0 <= t < best and ow + t * dw <= wall_h:
                    best, code, nu, nv, nw, mat = t, TWALL, 0.0, 1.0, 0.0, MAT_TWALL
            rho = seg[i, rt.ARC_R]
            if rho == 0.0:
                if dw > 1e-12:
                    t = (seg[i, rt.CROWN_H] - ow) / dw
                    if t0 <= t < best:
                        best, code, nu, nv, nw, mat = t, TCEIL, 0.0, 0.0, -1.0, MAT_TCEIL
            else:
                c = seg[i, rt.ARC_C]
                a = dv * dv + dw * dw
                if a > 1e-12:
                    b = 2.0 * (ov * dv + (ow - c) * dw)
                    cc = ov * ov + (ow - c) ** 2 - rho * rho
                    disc = b * b - 4.0 * a * cc
                    if disc > 0.0:
                        t = (-b + math.sqrt(disc)) / (2.0 * a)
                        wh = ow + t * dw
                        if t0 <= t < best and wh >= wall_h:
                            vh = ov + t * dv
                            best, code, mat = t, TCEIL, MAT_TCEIL
                            nu, nv, nw = 0.0, -vh / rho, -(wh - c) / rho
        elif seg[i, rt.KIND] == rt.KIND_TUNNEL:
            if dw < -1e-12:
                t = (seg[i, rt.HILL_H] - ow) / dw
                if t0 <= t < best:
                    best, code, nu, nv, nw, mat = t, HILLTOP, 0.0, 0.0, 1.0, MAT_HILL
        elif cull and dw >= 0.0 and ow + t0 * dw > seg[i, T_HMAX] + CULL_MARGIN_M:
            # light step: the ray piece [t0, best] rises (dw ≥ 0) from above the segment's highest surface, so every
            # test below would reject (ground: needs dw < 0; a block or box: w_min, the piece's lowest w minus
            # CULL_MARGIN_M, is above its top — the cull test's own rejection, reached without computing it)
            pass
        else:
            if dw < -1e-12:
                t = -ow / dw
                if t0 <= t < best:
                    best, code, nu, nv, nw, mat = t, GROUND, 0.0, 0.0, 1.0, MAT_VERGE
            # The part of the ray still in play is the straight piece [t0, best]: the local coordinates of its two
            # end points bound it, so a block or box it cannot reach is rejected with a few multiplications
            # instead of the divisions of the exact test (most rays pass most blocks and props; rays rising over
            # the roadside to the sky are rejected by their height). The exact test runs for everything not
            # rejected, so hits and their t are unchanged (CULL_MARGIN_M: far above the rounding of either test).
            # With cull=False every block and box takes the exact test (reference path for the tests).
            ua, ub = ou + t0 * du, ou + best * du
            va, vb = ov + t0 * dv, ov + best * dv
            wa, wb = ow + t0 * dw, ow + best * dw
            v_min, v_max = min(va, vb) - CULL_MARGIN_M, max(va, vb) + CULL_MARGIN_M
            w_min, w_max = min(wa, wb) - CULL_MARGIN_M, max(wa, wb) + CULL_MARGIN_M
            for sgn in (-1.0, 1.0):
                if sgn < 0:
                    off, h, m = seg[i, rt.L_OFF], seg[i, rt.L_H], seg[i, rt.L_MAT]
                    reach = -v_min > off  # the piece gets to the left of −off somewhere
                else:
                    off, h, m = seg[i, rt.R_OFF], seg[i, rt.R_H], seg[i, rt.R_MAT]
                    reach = v_max > off
                if off < rt.NO_BLOCK_OFFSET and ((reach and w_min < h) or not cull):
                    t, side = _block_entry(ov, ow, dv, dw, off, h, sgn)
                    if t0 <= t < best:
                        best, mat = t, int(m)
                        if side:
                            code, nu, nv, nw = SIDE, 0.0, -sgn, 0.0
                        else:
                            code, nu, nv, nw = ROOF, 0.0, 0.0, 1.0
                            mat = MAT_ROOF
            if any_hit and code >= 0:  # a block or the ground is in the way: whether a prop is nearer is moot
                return (best, code, i, i, inside, 0.0, 0.0, 0.0, nu, nv, nw, mat)
            u_min, u_max = min(ua, ub) - CULL_MARGIN_M, max(ua, ub) + CULL_MARGIN_M
            for b in range(int(seg[i, rt.N_BOXES])):
                col = rt.BOX0 + rt.BOX_STRIDE * b
                if cull and (u_max < seg[i, col] or u_min > seg[i, col + 1] or v_max < seg[i, col + 2]
                             or v_min > seg[i, col + 3] or w_max < seg[i, col + 4] or w_min > seg[i, col + 5]):
                    continue  # the piece's bounding box misses the prop's box
                t, bu, bv, bw = _box_hit(seg, i, col, ou, ov, ow, du, dv, dw, t0, best)
                if t < best:
                    best, code, nu, nv, nw, mat = t, PROP, bu, bv, bw, int(seg[i, col + 6])
                    if any_hit:
                        return (best, code, i, i, inside, 0.0, 0.0, 0.0, nu, nv, nw, mat)
        if code >= 0:
            return (best, code, i, i, inside, ou + best * du, ov + best * dv, ow + best * dw, nu, nv, nw, mat)
        if t_exit >= tmax:
            if dz < 0.0:
                return INF, FAR, i, i, inside, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, MAT_VERGE
            return INF, SKY, i, i, inside, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1
        # cross into the neighbouring segment
        t0 = t_exit
        j = (i + dirn) % nseg
        px, py, pz = ox + t0 * dx, oy + t0 * dy, oz + t0 * dz
        pu = _dot(seg, j, rt.F, px - seg[j, 0], py - seg[j, 1], pz - seg[j, 2])
        pv = _dot(seg, j, rt.R, px - seg[j, 0], py - seg[j, 1], pz - seg[j, 2])
        pw = _dot(seg, j, rt.U, px - seg[j, 0], py - seg[j, 1], pz - seg[j, 2])
        if abs(pv) > seg[j, rt.VMAX]:
            if dz < 0.0:
                return INF, FAR, j, j, False, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, MAT_VERGE
            return INF, SKY, j, j, False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1
        if seg[j, rt.KIND] == rt.KIND_TUNNEL:
            if seg[i, rt.KIND] != rt.KIND_TUNNEL:
                if inside_profile(seg, j, pv, pw):
                    inside = True
                elif pw < seg[j, rt.HILL_H]:
                    return (t0, FACE, j, i, inside, pu, pv, pw, -float(dirn), 0.0, 0.0, MAT_PORTAL)
                else:
                    inside = False
        else:
            inside = False
            if pv < -seg[j, rt.L_OFF] and pw < seg[j, rt.L_H]:
                return (t0, FACE, j, i, False, pu, pv, pw, -float(dirn), 0.0, 0.0, int(seg[j, rt.L_MAT]))
            if pv > seg[j, rt.R_OFF] and pw < seg[j, rt.R_H]:
                return (t0, FACE, j, i, False, pu, pv, pw, -float(dirn), 0.0, 0.0, int(seg[j, rt.R_MAT]))
        i = j
    return INF, SKY, i, i, inside, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1


@njit(cache=True)
def spread_stride(n):
    """A stride s coprime with n near n/φ, so row(k) = (k·s) mod n is a permutation of 0…n−1 in which every run of
    consecutive k is spread nearly evenly over 0…n−1 (three-distance theorem).

    Why: numba's prange hands each thread one contiguous block of iterations, and image rows differ in cost (rising
    sky rays walk many segments; ground rows sample textures and cast shadow rays), with the dearer half of the
    image changing from frame to frame (measured on the benchmark frames at 320×240: up to 35 %, on average 10 %
    more work in one half than the other), so one of two threads idled at the end of a frame. Iterating k and
    rendering row(k) gives every thread the same mix. Rows are independent, so the image is bit-identical."""
    if n <= 2:
        return 1
    s = max(1, int(n * 0.6180339887498949 + 0.5))
    while True:
        a, b = s, n
        while b:
            a, b = b, a % b
        if a == 1:
            return s
        s += 1


@njit(cache=True, inline="always")
def _hash01(a, b):
    h = (a * 374761393 + b * 668265263) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return h / 4294967296.0


@njit(cache=True, inline="always")
def _bilinear(texels, base, n, x, y, out, weight):
    """Add weight × bilinear sample (wrap-around) of the (n, n, 3) level at texel coords (x, y).

    Level sizes are powers of two (tile_px is validated to 256…2048 and every mip level halves it), so the wrap is a
    bit mask: for a power of two n, `i & (n − 1)` equals Python's `i % n` for negative i too, without the four
    integer divisions per level (measured on 0.7 M recorded samples: 174 → 92 ns per trilinear sample)."""
    x -= 0.5
    y -= 0.5
    fx0 = math.floor(x)
    fy0 = math.floor(y)
    ax = x - fx0
    ay = y - fy0
    mask = n - 1
    x0 = int(fx0) & mask
    y0 = int(fy0) & mask
    x1 = (x0 + 1) & mask
    y1 = (y0 + 1) & mask
    row0 = base + y0 * n * 3
    row1 = base + y1 * n * 3
    bx = 1 - ax
    by = 1 - ay
    for c in range(3):
        v00 = texels[row0 + x0 * 3 + c]
        v01 = texels[row0 + x1 * 3 + c]
        v10 = texels[row1 + x0 * 3 + c]
        v11 = texels[row1 + x1 * 3 + c]
        out[c] += weight * ((v00 * bx + v01 * ax) * by + (v10 * bx + v11 * ax) * ay)


@njit(cache=True, inline="always")
def sample_texture(texels, offs, sizes, scales, mat, a_m, b_m, footprint_m, texel_m, out):
    """Trilinear mip sample of material `mat` at surface coords (a along the route, b across/up) in metres."""
    n0 = sizes[mat, 0]
    tile_m = n0 * texel_m
    cell = int(math.floor(a_m / tile_m))
    shift = _hash01(cell, mat + 17) * tile_m  # random tile offset per cell: breaks periodicity along the route
    a = a_m + shift
    nlev = sizes.shape[1]
    lev = math.log2(max(footprint_m / texel_m, 1e-6))
    lev = min(max(lev, 0.0), nlev - 1.0)
    l0 = int(lev)
    fr = lev - l0
    l1 = min(l0 + 1, nlev - 1)
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    # texel coordinates at level l: a / (texel_m·2^l) = (a / texel_m)·2^−l bit for bit (scaling by a power of two
    # is exact and commutes with rounding; levels ≤ 11, far from underflow), so one division per axis serves both
    # levels instead of two
    qa = a / texel_m
    qb = b_m / texel_m
    k0 = 1.0 / (1 << l0)
    _bilinear(texels, offs[mat, l0], sizes[mat, l0], qa * k0, qb * k0, out, 1.0 - fr)
    if fr > 0.0:
        k1 = 1.0 / (1 << l1)
        _bilinear(texels, offs[mat, l1], sizes[mat, l1], qa * k1, qb * k1, out, fr)
    k = scales[mat] / 255.0
    out[0] *= k
    out[1] *= k
    out[2] *= k


@njit(cache=True, inline="always")
def box_cover(x, half, c, half_w):
    """Fraction of the box [x−half, x+half] covered by [c−half_w, c+half_w]."""
    lo = max(x - half, c - half_w)
    hi = min(x + half, c + half_w)
    return max(0.0, hi - lo) / (2.0 * half)


@njit(cache=True, inline="always")
def _dash_integral(x, period, on):
    return math.floor(x / period) * on + min(x - math.floor(x / period) * period, on)


@njit(cache=True, inline="always")
def dash_cover(x, half, period, on, phase):
    """Fraction of [x−half, x+half] covered by a periodic dash pattern (on-length `on`, starting at `phase`)."""
    return (_dash_integral(x + half - phase, period, on) - _dash_integral(x - half - phase, period, on)) / (2 * half)
