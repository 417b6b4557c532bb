"""Closed route geometry: the analytic centreline and the segment table the ray caster walks.

World frame: x east, y north, z up (metres). The centreline is a chain of straights and circular arcs; heading ψ is
measured counter-clockwise from +x. The height profile z(s) = a·sin(2π·cycles·s/L) closes by construction.

The renderer sees the route as a chain of *segments*: straight chords (arcs are split into chords of at most
`arc_chord_m`), each with a local frame (u forward along the chord incl. grade, v to the right, w up) and one
cross-section: open road with a roadside block on each side, or a tunnel (box/arch) under a hill. Neighbouring
segments meet at mitred planes (normal = bisector of the two chord directions), so a ray walks from segment to
segment by plane crossings.
"""

from __future__ import annotations

import math

import numpy as np

from expoctl.world.cities import route_length_m

# --- segment table columns (float64), shared with the ray caster
P0, F, R, U, NS, NE, P1 = 0, 3, 6, 9, 12, 15, 18  # 3-vectors: start point, forward, right, up, start/end plane normals, end point
LEN, S0, KIND = 21, 22, 23  # chord length, arc length at start, 0 open / 1 tunnel
HW, WALL_H, CROWN_H, ARC_C, ARC_R, HILL_H = 24, 25, 26, 27, 28, 29  # tunnel half width, wall height, crown, arch circle
TUN_ID, TUN_S0, TUN_LEN = 30, 31, 32
L_OFF, L_H, L_MAT, R_OFF, R_H, R_MAT = 33, 34, 35, 36, 37, 38  # roadside blocks: offset from centreline, height, material
VMAX = 39  # lateral validity of this segment's slab (mitre planes of arcs converge at the circle centre)
BOX0, BOX_STRIDE, MAX_BOXES = 40, 7, 4  # roadside props as local axis-aligned boxes: u0, u1, v0, v1, w0, w1, material
N_BOXES = BOX0 + BOX_STRIDE * MAX_BOXES
NCOL = N_BOXES + 1

KIND_OPEN, KIND_TUNNEL = 0.0, 1.0
NO_BLOCK_OFFSET = 1.0e6


class Route:
    """Analytic centreline of a closed route (config: city['route'])."""

    def __init__(self, city_cfg: dict):
        self.cfg = city_cfg
        self.length_m = route_length_m(city_cfg)
        route = city_cfg["route"]
        self.grade_amplitude_m = float(route["grade_amplitude_m"])
        self.grade_cycles = int(route["grade_cycles"])
        x, y, psi = 0.0, 0.0, 0.0
        s = 0.0
        self.pieces = []  # (s_start, length, curvature, x0, y0, psi0)
        for p in route["pieces"]:
            if "straight_m" in p:
                length, kappa = float(p["straight_m"]), 0.0
            else:
                length = float(p["arc_radius_m"]) * math.radians(abs(float(p["arc_angle_deg"])))
                kappa = math.copysign(1.0 / float(p["arc_radius_m"]), float(p["arc_angle_deg"]))
            self.pieces.append((s, length, kappa, x, y, psi))
            x, y, psi = _advance(x, y, psi, kappa, length)
            s += length
        self._piece_s = np.array([p[0] for p in self.pieces])

    def wrap(self, s):
        return np.mod(s, self.length_m)

    def centre(self, s):
        """Centreline at arc length s (any shape): x, y, z, heading ψ (rad), dz/ds."""
        s = self.wrap(np.asarray(s, dtype=np.float64))
        idx = np.clip(np.searchsorted(self._piece_s, s, side="right") - 1, 0, len(self.pieces) - 1)
        table = np.array([p[1:] for p in self.pieces])  # length, kappa, x0, y0, psi0
        _, kappa, x0, y0, psi0 = (table[idx, k] for k in range(5))
        ds = s - self._piece_s[idx]
        straight = np.abs(kappa) < 1e-12
        k_safe = np.where(straight, 1.0, kappa)
        psi = psi0 + kappa * ds
        x = np.where(straight, x0 + ds * np.cos(psi0), x0 + (np.sin(psi) - np.sin(psi0)) / k_safe)
        y = np.where(straight, y0 + ds * np.sin(psi0), y0 - (np.cos(psi) - np.cos(psi0)) / k_safe)
        w = 2 * math.pi * self.grade_cycles / self.length_m
        z = self.grade_amplitude_m * np.sin(w * s)
        dz = self.grade_amplitude_m * w * np.cos(w * s)
        return x, y, z, psi, dz

    def min_radius_at(self, s0: float, s1: float) -> float:
        """Smallest arc radius overlapping [s0, s1] (inf on straights)."""
        r = math.inf
        for ps, length, kappa, *_ in self.pieces:
            if kappa != 0.0 and ps < s1 and ps + length > s0:
                r = min(r, 1.0 / abs(kappa))
        return r


def _advance(x, y, psi, kappa, length):
    if kappa == 0.0:
        return x + length * math.cos(psi), y + length * math.sin(psi), psi
    psi1 = psi + kappa * length
    return x + (math.sin(psi1) - math.sin(psi)) / kappa, y - (math.cos(psi1) - math.cos(psi)) / kappa, psi1


MATERIAL_IDS = {"road": 0, "sidewalk": 1, "verge": 2, "facade_a": 3, "facade_b": 4, "wall": 5, "hedge": 6,
                "tunnel_wall": 7, "tunnel_ceiling": 8, "portal": 9, "hill": 10, "roof": 11, "pole": 12, "sign": 13}


def _roadside_blocks(cfg: dict, route: Route, rng: np.random.Generator):
    """Random roadside blocks along the route: list of (s0, s1, (offL, hL, matL), (offR, hR, matR))."""
    rs = cfg["roadside"]
    kinds = list(rs["kinds"].keys())
    probs = np.array([rs["kinds"][k] for k in kinds], dtype=float)
    probs /= probs.sum()
    heights = {"facade_a": 1.0, "facade_b": 1.0, "wall": 0.25, "hedge": 0.15}
    blocks, s = [], 0.0
    while s < route.length_m - 1e-6:
        length = min(rng.uniform(*rs["block_length_m"]), route.length_m - s)
        sides = []
        for _ in range(2):
            kind = kinds[rng.choice(len(kinds), p=probs)]
            if kind == "none":
                sides.append((NO_BLOCK_OFFSET, 0.0, 0.0))
                continue
            h = rng.uniform(*rs["height_m"])
            # walls and hedges are low: scale their height toward 1.5–5 m
            h = max(1.2, h * heights[kind]) if kind in ("wall", "hedge") else h
            sides.append((rng.uniform(*rs["offset_m"]), h, float(MATERIAL_IDS[kind])))
        blocks.append((s, s + length, sides[0], sides[1]))
        s += length
    return blocks


def build_segments(cfg: dict, route: Route) -> np.ndarray:
    """The (N, NCOL) segment table for the ray caster."""
    rng = np.random.default_rng([int(cfg["seed"]), 11])
    L = route.length_m
    cuts = {0.0}
    for ps, length, kappa, *_ in route.pieces:
        cuts.add(ps)
        if kappa != 0.0:
            n = max(1, math.ceil(length / float(cfg["route"]["arc_chord_m"])))
            cuts.update(ps + length * k / n for k in range(1, n))
    blocks = _roadside_blocks(cfg, route, rng)
    cuts.update(b[0] for b in blocks)
    approach = float(cfg["roadside"]["approach_m"])
    for t in cfg["tunnels"]:
        a, b = float(t["start_m"]), float(t["start_m"]) + float(t["length_m"])
        cuts.update([a, b, (a - approach) % L, (b + approach) % L])
    cuts = np.array(sorted(c % L for c in cuts))
    cuts = cuts[np.concatenate([[True], np.diff(cuts) > 0.05])]
    if L - cuts[-1] < 0.05:
        cuts = cuts[:-1]
    s_start = cuts
    s_end = np.append(cuts[1:], L)
    x, y, z, _, _ = route.centre(s_start)
    pts = np.stack([x, y, z], axis=1)
    nxt = np.roll(pts, -1, axis=0)
    fwd = nxt - pts
    length = np.linalg.norm(fwd, axis=1)
    fwd /= length[:, None]
    right = np.cross(fwd, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right, axis=1)[:, None]
    up = np.cross(right, fwd)
    prev_f = np.roll(fwd, 1, axis=0)
    n_start = prev_f + fwd
    n_start /= np.linalg.norm(n_start, axis=1)[:, None]
    n_end = np.roll(n_start, -1, axis=0)

    seg = np.zeros((len(s_start), NCOL))
    seg[:, P0:P0 + 3], seg[:, F:F + 3], seg[:, R:R + 3], seg[:, U:U + 3] = pts, fwd, right, up
    seg[:, NS:NS + 3], seg[:, NE:NE + 3], seg[:, P1:P1 + 3] = n_start, n_end, nxt
    seg[:, LEN], seg[:, S0] = length, s_start
    seg[:, TUN_ID] = -1
    mid = 0.5 * (s_start + s_end)
    road = cfg["road"]
    road_half = road["lanes"] * road["lane_width_m"] / 2 + road["shoulder_m"]
    block_s0 = np.array([b[0] for b in blocks])
    for i in range(len(seg)):
        r = route.min_radius_at(s_start[i] - 1.0, s_end[i] + 1.0)
        seg[i, VMAX] = min(400.0, 0.85 * r)
        b = blocks[int(np.searchsorted(block_s0, mid[i], side="right") - 1)]
        (seg[i, L_OFF], seg[i, L_H], seg[i, L_MAT]), (seg[i, R_OFF], seg[i, R_H], seg[i, R_MAT]) = b[2], b[3]
    for ti, t in enumerate(cfg["tunnels"]):
        a, b = float(t["start_m"]), float(t["start_m"]) + float(t["length_m"])
        hw, h = float(t["width_m"]) / 2, float(t["height_m"])
        inside = (mid > a) & (mid < b)
        seg[inside, KIND] = KIND_TUNNEL
        seg[inside, HW], seg[inside, CROWN_H], seg[inside, HILL_H] = hw, h, float(t["hill_height_m"])
        if t["profile"] == "box":
            seg[inside, WALL_H], seg[inside, ARC_C], seg[inside, ARC_R] = h, 0.0, 0.0
        else:  # vertical walls to 55 % of the crown, then a circular arc through (±hw, wall_h) and (0, h)
            wall_h = 0.55 * h
            c = (h * h - hw * hw - wall_h * wall_h) / (2 * (h - wall_h))
            seg[inside, WALL_H], seg[inside, ARC_C], seg[inside, ARC_R] = wall_h, c, h - c
        seg[inside, TUN_ID], seg[inside, TUN_S0], seg[inside, TUN_LEN] = ti, a, b - a
        # the approach cutting: retaining walls in line with the tunnel walls, half the hill height
        near = ((mid > a - approach) & (mid < a)) | ((mid > b) & (mid < b + approach))
        if a - approach < 0:
            near |= mid > (a - approach) % L
        if b + approach > L:
            near |= mid < (b + approach) % L
        for off, hh, mat in ((L_OFF, L_H, L_MAT), (R_OFF, R_H, R_MAT)):
            seg[near, off] = hw
            seg[near, hh] = 0.5 * float(t["hill_height_m"])
            seg[near, mat] = MATERIAL_IDS["portal"]
    for off in (L_OFF, R_OFF):  # blocks never intrude into the road + sidewalk
        seg[:, off] = np.maximum(seg[:, off], road_half + 0.5)
    _place_props(cfg, seg, rng, road_half)
    return seg


def _place_props(cfg: dict, seg: np.ndarray, rng: np.random.Generator, road_half: float) -> None:
    """Poles with sign panels on the sidewalk of open segments (parallax-rich, non-periodic features)."""
    density = float(cfg["roadside"]["props_per_100m"]) / 100.0
    sidewalk = float(cfg["road"]["sidewalk_m"])
    for i in range(len(seg)):
        if seg[i, KIND] != KIND_OPEN or seg[i, LEN] < 2.0:
            continue
        n = 0
        for side in (-1.0, 1.0):
            if rng.random() >= min(1.0, density * seg[i, LEN] / 2.0) or n + 2 > MAX_BOXES:
                continue
            off = seg[i, L_OFF] if side < 0 else seg[i, R_OFF]
            v = road_half + rng.uniform(0.3, max(0.4, min(sidewalk, off - road_half) - 0.3))
            u = rng.uniform(0.5, seg[i, LEN] - 0.5)
            h = rng.uniform(2.5, 6.0)
            r = 0.06 if rng.random() < 0.7 else 0.12
            col = BOX0 + BOX_STRIDE * n
            seg[i, col:col + 7] = (u - r, u + r, side * v - r, side * v + r, 0.0, h, MATERIAL_IDS["pole"])
            n += 1
            if rng.random() < 0.8:  # a sign panel facing the traffic, toward the road side of the pole
                w = rng.uniform(0.5, 1.6)
                ph = rng.uniform(0.4, 1.2)
                v0 = side * v - (w if side > 0 else 0.0)
                col = BOX0 + BOX_STRIDE * n
                seg[i, col:col + 7] = (u - r - 0.04, u - r, v0, v0 + w, h - ph, h, MATERIAL_IDS["sign"])
                n += 1
        seg[i, N_BOXES] = n
