"""Daylight entering a tunnel through its portals: the configuration (view) factor of each portal opening seen from a
point on a tunnel surface, times the luminance seen through that opening.

Illuminance at a surface point P (unit normal n) from an opening of uniform luminance L: E = π·L·F, with F the
configuration factor from the differential area at P to the opening. For a planar polygon with vertices r_k (relative to
P, all on the visible side of P's tangent plane) F has an exact closed form — the contour integral of Stokes' theorem
applied to the projected solid angle (Lambert's polygon formula; Howell's catalogue of configuration factors derives its
plane-element-to-rectangle cases, parallel and perpendicular, from it):
    F = |Σ_k θ_k · n·(r_k × r_k+1) / |r_k × r_k+1|| / (2π),   θ_k = angle between r_k and r_k+1.
The opening is the tunnel cross-section (box: the width × height rectangle; arch: its own profile, not an equivalent
rectangle — vertical walls to the springing line, then the circular arch as ARC_EDGES chords, an inscribed polygon
whose area is 0.7 % short of the test city's arch, so its F is 0.2–1.3 % short for road points 2–20 m from the
portal, tests/world/test_daylight.py), in the plane through the portal perpendicular to the tunnel axis at distance X
along the axis from P. The
cross-section is convex and P lies on its boundary with an inward normal, so no part of the opening is behind P's tangent
plane and the formula needs no clipping.

With every vertex at the same axial distance X, r_k = (X, V_k, W_k) (V, W: cross-section coordinates of the vertex
minus those of P) and n = (0, n_v, n_w) (tunnel surfaces: road up, walls sideways, ceiling/arch inward), so
    r_a × r_b = (V_a W_b − W_a V_b,  X (W_a − W_b),  X (V_b − V_a)),   n·(r_a × r_b) = X (n_v (W_a − W_b) + n_w (V_b − V_a)).
The kernel evaluates each edge's term in a rearranged, cancellation-free form (_edge).

The opening's part below P's height (G ≤ F) is the polygon clipped to W ≤ w: rays through it descend and see the
ground outside, the rest rise; E = π·(L_up·(F − G) + L_down·G), L_up / L_down from portal_views.portal_luminances.

Assumptions (documented limits): the tunnel is straight between P and the portal (X = distance along the tunnel; in a
curved tunnel the bend hides part of the opening, so this overestimates deep inside a bend); the opening has one mean
luminance for rising and one for descending rays (portal_views.portal_luminances); light reflected by the tunnel's own
surfaces is not added. The direct sun is not in this term: it stays traced by the shadow ray, and the opening
luminance is estimated without the sun's disk.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

ARC_EDGES = 8  # chords approximating an arch's circular part (2³: opening_factors_inline halves the angle thrice)


def cross_section_polygon(hw: float, wall_h: float, crown_h: float, arc_c: float, arc_r: float) -> np.ndarray:
    """Vertices (V, W) of a tunnel cross-section in metres (V across, W up from the road), counter-clockwise from the
    road's left edge. Box: arc_r == 0 (height crown_h). Arch: walls to wall_h, then the circle (0, arc_c), radius arc_r."""
    pts = [(-hw, 0.0), (hw, 0.0)]
    if arc_r == 0.0:
        pts += [(hw, crown_h), (-hw, crown_h)]
    else:
        a0 = math.atan2(wall_h - arc_c, hw)
        step = (math.pi - 2.0 * a0) / ARC_EDGES
        pts += [(arc_r * math.cos(a0 + k * step), arc_c + arc_r * math.sin(a0 + k * step)) for k in range(ARC_EDGES)]
        pts += [(-hw, wall_h)]
    return np.array(pts)


def polygon_view_factor(point: np.ndarray, normal: np.ndarray, vertices: np.ndarray) -> float:
    """Configuration factor from a differential area (point, unit normal; 3-vectors) to a planar polygon (K, 3) lying
    wholly on the normal's side of the area's tangent plane (Lambert's contour formula, module docstring)."""
    r = np.asarray(vertices, dtype=np.float64) - np.asarray(point, dtype=np.float64)
    total = 0.0
    for k in range(len(r)):
        a, b = r[k], r[(k + 1) % len(r)]
        c = np.cross(a, b)
        nc = float(np.linalg.norm(c))
        if nc > 0.0:
            total += math.atan2(nc, float(a @ b)) * float(np.asarray(normal) @ c) / nc
    return abs(total) / (2.0 * math.pi)


def clip_below(poly: np.ndarray, w: float) -> np.ndarray:
    """The part W ≤ w of a convex polygon (K, 2) of (V, W) vertices (Sutherland–Hodgman; empty → (0, 2))."""
    out = []
    for k in range(len(poly)):
        a, b = poly[k], poly[(k + 1) % len(poly)]
        a_in, b_in = a[1] <= w, b[1] <= w
        if a_in:
            out.append(a)
        if a_in != b_in:
            out.append(a + (b - a) * (w - a[1]) / (b[1] - a[1]))
    return np.array(out).reshape(-1, 2)


def opening_factor(x_m: float, v: float, w: float, nv: float, nw: float, hw: float, wall_h: float, crown_h: float,
                   arc_c: float, arc_r: float, below: bool = False) -> float:
    """Configuration factor of a portal opening at axial distance x_m from a tunnel-surface point at (v, w) with normal
    (0, nv, nw) in the cross-section frame; below=True: of the opening's part below the point's height (numpy
    reference of the kernel's opening_factors_inline)."""
    poly = cross_section_polygon(hw, wall_h, crown_h, arc_c, arc_r)
    if below:
        poly = clip_below(poly, w)
        if len(poly) < 3:
            return 0.0
    verts = np.column_stack([np.full(len(poly), max(x_m, 1.0e-3)), poly])
    return polygon_view_factor(np.array([0.0, v, w]), np.array([0.0, nv, nw]), verts)


@njit(cache=True, inline="always")
def _edge(x0, x1, va, wa, vb, wb, nv, nw):
    """One edge's terms of the contour sum for the two portals (axial distances x0, x1), each minus m/x:
    θ·n·(r_a × r_b)/|r_a × r_b| − m/x for r = (x, V, W) and n = (0, nv, nw), m = nv·(W_a − W_b) + nw·(V_b − V_a)
    (module docstring).

    Why minus m/x: seen from afar (x ≫ the opening) every term is ≈ m/x and their sum cancels to the much smaller F
    (Σ m = 0 exactly around a closed polygon) — in float32 (the GL port) that cancellation cost ~1e-4 of F at 100 m.
    With D = V_a W_b − W_a V_b, L the edge length, |r_a × r_b| = √(D² + x²L²) =: N, P = V_a V_b + W_a W_b and
    tan θ = T = N/(x² + P), the term is θ·x·m/N; since x·m·T/N = x·m/(x² + P), exactly
        θ·x·m/N − m/x = x·m·(atan T − T)/N − m·P/(x·(x² + P))
    whose two parts are each of the order of the result (no cancellation of the leading terms)."""
    dv = vb - va
    dw = wa - wb
    m = nv * dw + nw * dv
    if m == 0.0:  # an edge parallel to the surface normal (walls seen from the road, …) adds nothing
        return 0.0, 0.0
    l2 = dv * dv + dw * dw
    d = va * wb - wa * vb
    d2 = d * d
    pp = va * vb + wa * wb
    return _edge_at(x0, d2, l2, pp, m), _edge_at(x1, d2, l2, pp, m)


@njit(cache=True, inline="always")
def _atan_minus_t(t):
    """atan(t) − t for t ≥ 0: for t ≤ 1/4 the series −t³/3 + t⁵/5 − … (12 terms: below 1e-15 relative), cheaper than
    the library atan and free of the cancellation atan(t) − t has for small t; else the library."""
    if t > 0.25:
        return math.atan(t) - t
    z = t * t
    q = 1.0 / 27.0  # q = 1/3 − z/5 + z²/7 − … (Horner)
    for k in range(12, 0, -1):
        q = 1.0 / (2 * k + 1) - z * q
    return -t * z * q


@njit(cache=True, inline="always")
def _edge_at(x, d2, l2, pp, m):
    """_edge's term at one axial distance x (D², L², P and m of the edge)."""
    nc = math.sqrt(d2 + x * x * l2)
    p = x * x + pp
    if p > 0.0:
        ip = 1.0 / p  # two divisions per edge and portal, not three: the kernel runs this 4–22 times per pixel
        t = nc * ip
        return m * (x * _atan_minus_t(t) / nc - pp * ip / x)
    return m * (x * math.atan2(nc, p) / nc - 1.0 / x)  # an edge seen under more than 90°: only near the portal


@njit(cache=True, inline="always")
def opening_factors_inline(hw, wall_h, crown_h, arc_c, arc_r, x0, x1, v, w, nv, nw):
    """Configuration factors of a tunnel's two openings, at axial distances x0 and x1 (m), from the surface point
    (v, w) with normal (0, nv, nw): (F0, F1) of the whole openings and (G0, G1) of their parts below the point's own
    height w — the rays through those descend and see the ground outside, the rest rise and see walls, facades and sky
    (portal_views gives each part its luminance). One walk over the cross-section's edges serves all four; the lower
    part is the polygon clipped to W ≤ w (Sutherland–Hodgman, streamed along the same walk)."""
    x0 = max(x0, 1.0e-3)  # at the portal plane itself the formula's limit (F = 1/2 on the road) is reached smoothly
    x1 = max(x1, 1.0e-3)
    f0 = 0.0
    f1 = 0.0
    g0 = 0.0
    g1 = 0.0
    top = crown_h if arc_r == 0.0 else wall_h
    # the road (w = 0) sees nothing below itself; the box ceiling sees the whole opening below (G = F, set at the end)
    low = w > 1.0e-6 and not (arc_r == 0.0 and w >= crown_h - 1.0e-6)
    wc = w if w < top else top  # the clip line within the walls' height
    bl_v, bl_w = -hw - v, -w  # bottom-left corner, relative to the point
    br_v, br_w = hw - v, -w
    # bottom edge
    e0, e1 = _edge(x0, x1, bl_v, bl_w, br_v, br_w, nv, nw)
    f0 += e0
    f1 += e1
    if low:
        g0 += e0
        g1 += e1
        # the lower part's right wall, up to the clip line or the springing line
        e0, e1 = _edge(x0, x1, br_v, br_w, br_v, wc - w, nv, nw)
        g0 += e0
        g1 += e1
    # right wall (box: to the ceiling; arch: to the springing line)
    pv, pw = hw - v, top - w
    e0, e1 = _edge(x0, x1, br_v, br_w, pv, pw, nv, nw)
    f0 += e0
    f1 += e1
    # exit point of the lower part's boundary on the clip line (where the walk first rises above w)
    out_v, out_w = br_v, wc - w
    if arc_r > 0.0:
        # arch: chords from angle a0 to π − a0 around (0, arc_c), vertices by rotation (one sin/cos pair per pixel)
        ca, sa = hw / arc_r, (wall_h - arc_c) / arc_r  # cos, sin of a0
        # the chord angle (π − 2·a0)/8 by three half-angle steps from cos(π − 2·a0) = sin²a0 − cos²a0: square roots
        # instead of atan2, cos and sin (the angle is in (0, π), so every half-angle cosine and sine is positive)
        cs = sa * sa - ca * ca
        for _ in range(3):
            cs = math.sqrt(max(0.0, 0.5 * (1.0 + cs)))
        sn = math.sqrt(max(0.0, 1.0 - cs * cs))
        for _ in range(ARC_EDGES):
            ca, sa = ca * cs - sa * sn, sa * cs + ca * sn
            qv, qw = arc_r * ca - v, arc_c + arc_r * sa - w
            e0, e1 = _edge(x0, x1, pv, pw, qv, qw, nv, nw)
            f0 += e0
            f1 += e1
            if low and w > wall_h:  # clip the chord to W ≤ w (relative: qw ≤ 0)
                p_in, q_in = pw <= 0.0, qw <= 0.0
                if p_in and q_in:
                    g0 += e0
                    g1 += e1
                elif p_in or q_in:
                    iv = pv + (qv - pv) * (0.0 - pw) / (qw - pw)  # the chord's crossing of the clip line
                    if p_in:  # leaving: the part up to the crossing
                        e0, e1 = _edge(x0, x1, pv, pw, iv, 0.0, nv, nw)
                        out_v, out_w = iv, 0.0
                    else:  # entering: the cut along the clip line, then the rest of the chord
                        e0, e1 = _edge(x0, x1, out_v, out_w, iv, 0.0, nv, nw)
                        g0 += e0
                        g1 += e1
                        e0, e1 = _edge(x0, x1, iv, 0.0, qv, qw, nv, nw)
                    g0 += e0
                    g1 += e1
            pv, pw = qv, qw
    else:
        qv, qw = -hw - v, crown_h - w
        e0, e1 = _edge(x0, x1, pv, pw, qv, qw, nv, nw)
        f0 += e0
        f1 += e1
        pv, pw = qv, qw
    if low and w <= wall_h:
        # below the springing line (every clipped box): the lower part is the rectangle [−hw, hw] × [0, w]
        e0, e1 = _edge(x0, x1, br_v, 0.0, bl_v, 0.0, nv, nw)  # the cut (relative w = 0)
        g0 += e0
        g1 += e1
        e0, e1 = _edge(x0, x1, bl_v, 0.0, bl_v, bl_w, nv, nw)
        g0 += e0
        g1 += e1
    elif low:
        # above the springing line: the lower part's left wall, down from the springing line
        e0, e1 = _edge(x0, x1, pv, pw, bl_v, bl_w, nv, nw)
        g0 += e0
        g1 += e1
    # left wall back down to the road edge
    e0, e1 = _edge(x0, x1, pv, pw, bl_v, bl_w, nv, nw)
    f0 += e0
    f1 += e1
    k = 1.0 / (2.0 * math.pi)
    f0, f1 = abs(f0) * k, abs(f1) * k
    if arc_r == 0.0 and w >= crown_h - 1.0e-6:
        return f0, f1, f0, f1
    return f0, f1, abs(g0) * k, abs(g1) * k


# ---------------------------------------------------------------------------------------------- light map (opt-in)
# The configuration factors depend only on the surface point, not on the frame: a table per tunnel, built once, read
# by the kernel instead of the per-pixel integral when world.render.portal_daylight is light_map (its registered
# error bound and measurements: docs/simulator.md). Per surface (LM_ROAD, LM_WALL: both walls by mirror symmetry,
# LM_CEIL: box ceiling or arch), a grid uniform in √X (X: axial distance to the portal; F changes fastest near the
# portal and falls as ~1/X² far from it: the relative step in X, 2·Δ√X/√X, shrinks as F flattens; a square root per
# lookup, where log(1 + X/a) cost three logarithms per pixel and most of the map's gain) and over the position
# across the surface; values (F, G) of one opening at distance X — both portals read the same table.
LM_ROAD, LM_WALL, LM_CEIL = 0, 1, 2
LIGHT_MAP_NX, LIGHT_MAP_NP = 512, 129
LIGHT_MAP_EXACT_M = 1.0  # nearer a portal plane than this: the exact integral (light_map_factors)
NO_LIGHT_MAP = np.zeros((0, 3, 2, 2, 2))  # no tunnel rows: the kernel integrates per pixel (the exact path)


@njit(cache=True, inline="always")
def _arch_a0(hw, wall_h, arc_c):
    return math.atan2(wall_h - arc_c, hw)  # springing-line angle of the arch circle


@njit(cache=True)
def _fill_light_map(out, hw, wall_h, crown_h, arc_c, arc_r, length):
    nx, npos = out.shape[1], out.shape[2]
    ds = math.sqrt(length) / (nx - 1)
    a0 = _arch_a0(hw, wall_h, arc_c)
    for surf in range(3):
        for ip in range(npos):
            q = ip / (npos - 1)
            if surf == LM_ROAD:
                v, w, nv, nw = -hw + 2.0 * hw * q, 0.0, 0.0, 1.0
            elif surf == LM_WALL:  # the left wall, normal +v (the right one is its mirror image)
                v, w, nv, nw = -hw, wall_h * q, 1.0, 0.0
            elif arc_r == 0.0:
                v, w, nv, nw = -hw + 2.0 * hw * q, crown_h, 0.0, -1.0
            else:
                th = a0 + (math.pi - 2.0 * a0) * q
                v, w, nv, nw = arc_r * math.cos(th), arc_c + arc_r * math.sin(th), -math.cos(th), -math.sin(th)
            for ix in range(nx):
                x = (ix * ds) ** 2
                f, _, g, _ = opening_factors_inline(hw, wall_h, crown_h, arc_c, arc_r, x, x, v, w, nv, nw)
                out[surf, ix, ip, 0] = f
                out[surf, ix, ip, 1] = g


def light_map(seg: np.ndarray, n_tunnels: int) -> np.ndarray:
    """(n_tunnels, 3 surfaces, LIGHT_MAP_NX, LIGHT_MAP_NP, (F, G)) for the tunnels of a segment table (route.py
    columns; every segment of a tunnel has its cross-section and length)."""
    from expoctl.world import route as rt

    out = np.zeros((n_tunnels, 3, LIGHT_MAP_NX, LIGHT_MAP_NP, 2))
    for tid in range(n_tunnels):
        rows = np.flatnonzero(seg[:, rt.TUN_ID] == tid)
        if len(rows) == 0:
            continue
        s = seg[rows[0]]
        _fill_light_map(out[tid], s[rt.HW], s[rt.WALL_H], s[rt.CROWN_H], s[rt.ARC_C], s[rt.ARC_R], s[rt.TUN_LEN])
    return out


@njit(cache=True, inline="always")
def _light_map_at(table, tid, surf, inv_ds, x, q):
    """Bilinear (F, G) of table[tid, surf] at axial distance x and surface position q ∈ [0, 1] (inv_ds: 1 / the
    grid's step in √X). Indexes the whole table: a slice per pixel would be a new array object in the pixel loop."""
    nx, npos = table.shape[2], table.shape[3]
    fu = min(math.sqrt(max(x, 0.0)) * inv_ds, nx - 1.0)
    ix = min(int(fu), nx - 2)
    tx = fu - ix
    fp = min(max(q, 0.0), 1.0) * (npos - 1)
    ip = min(int(fp), npos - 2)
    tp = fp - ip
    f = ((1 - tx) * ((1 - tp) * table[tid, surf, ix, ip, 0] + tp * table[tid, surf, ix, ip + 1, 0])
         + tx * ((1 - tp) * table[tid, surf, ix + 1, ip, 0] + tp * table[tid, surf, ix + 1, ip + 1, 0]))
    g = ((1 - tx) * ((1 - tp) * table[tid, surf, ix, ip, 1] + tp * table[tid, surf, ix, ip + 1, 1])
         + tx * ((1 - tp) * table[tid, surf, ix + 1, ip, 1] + tp * table[tid, surf, ix + 1, ip + 1, 1]))
    return f, g


@njit(cache=True, inline="always")
def light_map_factors(table, tid, surf, hw, wall_h, crown_h, arc_c, arc_r, length, x, v, w, nv, nw):
    """(F0, F1, G0, G1) as opening_factors_inline returns them, from tunnel tid's light map (table: light_map's),
    for a point at (v, w), normal (0, nv, nw), on surface surf (LM_ROAD, LM_WALL, LM_CEIL) at x from the tunnel's
    start. The exact integral instead:
    - within LIGHT_MAP_EXACT_M of either portal plane: there F changes within a few cm of the cross-section's corners
      (from ½ on the road to ¼ at its edge as X → 0), finer than the table resolves (measured with a log grid: up to
      17 % off at X = 2 cm, ≤ 0.19 % from X = 0.3 m);
    - for points off the surface's extent (a wall hit below the road or a ceiling hit beyond the walls: the ray caster
      meets such points where a curved tunnel's straight segments join; measured up to 4× off when clamped)."""
    if surf == LM_ROAD:
        q = (v + hw) / (2.0 * hw)
    elif surf == LM_WALL:
        q = w / wall_h
    elif arc_r == 0.0:
        q = (v + hw) / (2.0 * hw)
    else:
        a0 = _arch_a0(hw, wall_h, arc_c)
        q = (math.atan2(w - arc_c, v) - a0) / (math.pi - 2.0 * a0)
    if x < LIGHT_MAP_EXACT_M or length - x < LIGHT_MAP_EXACT_M or not 0.0 <= q <= 1.0:
        return opening_factors_inline(hw, wall_h, crown_h, arc_c, arc_r, x, length - x, v, w, nv, nw)
    inv_ds = (table.shape[2] - 1) / math.sqrt(length)
    f0, g0 = _light_map_at(table, tid, surf, inv_ds, x, q)
    f1, g1 = _light_map_at(table, tid, surf, inv_ds, length - x, q)
    return f0, f1, g0, g1
