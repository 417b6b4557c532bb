"""Flow matching of the libviso2-style matcher (spec §6): binned lookup, circle check, prior, integer refinement.

A match is a row (u_prev, v_prev, u_cur, v_cur) of int32 full-resolution pixel coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from expoctl.features.viso.descriptors import REFINE_DU_OFFSETS, REFINE_DV_OFFSETS
from expoctl.features.viso.sad import sad32

#: A prior range narrower than this (px) is widened symmetrically to it.
PRIOR_MIN_WIDTH = 20


@dataclass(frozen=True)
class FeatureSet:
    """Features of one image at full-resolution coordinates, with the lookup bins of the matcher.

    Bins: features sorted by key (class, u-cell, v-cell) with ties in index order; bin k holds the features
    order[start[k]:start[k+1]]. The search reads bin-ordered copies (su, sv, sdesc) so that a bin is contiguous in
    memory; rank is the inverse of order (the bin-ordered row of feature i).
    """

    u: np.ndarray  # int32
    v: np.ndarray  # int32
    cls: np.ndarray  # int8, 0..3
    desc: np.ndarray  # (N, 32) uint8
    order: np.ndarray  # int32
    start: np.ndarray  # int32, 4·n_cells_u·n_cells_v + 1
    rank: np.ndarray  # int32
    su: np.ndarray  # int32, u[order]
    sv: np.ndarray  # int32, v[order]
    sdesc: np.ndarray  # (N, 32) uint8, desc[order], C-contiguous

    def __len__(self) -> int:
        return len(self.u)


@dataclass(frozen=True)
class Grid:
    """Cells of `binsize` px over a width×height image: ceil(W/binsize) × ceil(H/binsize), index floor(x/binsize) clamped."""

    width: int
    height: int
    binsize: int

    @property
    def n_u(self) -> int:
        return -(-self.width // self.binsize)

    @property
    def n_v(self) -> int:
        return -(-self.height // self.binsize)

    def cells(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cu = np.clip(np.asarray(u) // self.binsize, 0, self.n_u - 1)
        cv = np.clip(np.asarray(v) // self.binsize, 0, self.n_v - 1)
        return cu, cv


def make_feature_set(u: np.ndarray, v: np.ndarray, cls: np.ndarray, desc: np.ndarray, grid: Grid) -> FeatureSet:
    cu, cv = grid.cells(u, v)
    key = (cls.astype(np.int64) * grid.n_u + cu) * grid.n_v + cv
    order = np.argsort(key, kind="stable").astype(np.int32)
    counts = np.bincount(key, minlength=4 * grid.n_u * grid.n_v)
    start = np.zeros(len(counts) + 1, np.int32)
    np.cumsum(counts, out=start[1:])
    desc = np.ascontiguousarray(desc, np.uint8)  # sad32 reads rows of 32 bytes by address
    if desc.shape != (len(u), 32):
        raise ValueError(f"descriptors must have shape ({len(u)}, 32), got {desc.shape}")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order), dtype=np.int32)
    u = u.astype(np.int32)
    v = v.astype(np.int32)
    return FeatureSet(u, v, cls.astype(np.int8), desc, order, start, rank, u[order], v[order],
                      np.ascontiguousarray(desc[order]))  # fmt: skip


@njit(cache=True)
def _cell(x, binsize, n_cells):
    c = int(np.floor(x / binsize))
    if c < 0:
        return 0
    if c > n_cells - 1:
        return n_cells - 1
    return c


@njit(cache=True)
def _search(qdesc, qi, c, umin, umax, vmin, vmax, su, sv, sdesc, order, start, n_u, n_v, binsize):
    """Index of the lowest-SAD feature of class c inside the inclusive window; 0 when there is none (libviso2 quirk).

    qdesc[qi] is the query descriptor. Candidates are visited in (u-cell, v-cell, index) order (the bin order of
    su, sv, sdesc) and the first of equal cost wins.
    """
    cu0 = _cell(umin, binsize, n_u)
    cu1 = _cell(umax, binsize, n_u)
    cv0 = _cell(vmin, binsize, n_v)
    cv1 = _cell(vmax, binsize, n_v)
    best = -1
    best_cost = 1 << 30
    for cu in range(cu0, cu1 + 1):
        for cv in range(cv0, cv1 + 1):
            k = (c * n_u + cu) * n_v + cv
            for p in range(start[k], start[k + 1]):
                if su[p] < umin or su[p] > umax or sv[p] < vmin or sv[p] > vmax:
                    continue
                cost = sad32(qdesc, qi, sdesc, p)
                if cost < best_cost:
                    best_cost = cost
                    best = p
    return order[best] if best >= 0 else 0


@njit(cache=True)
def _circle_match(pu, pv, pc, prank, psu, psv, psdesc, porder, pstart,
                  cu_, cv_, cc, crank, csu, csv, csdesc, corder, cstart,
                  n_u, n_v, binsize, width, height, radius, use_prior, prior):  # fmt: skip
    n_cur = len(cu_)
    out = np.empty((n_cur, 4), np.int32)
    occupied = np.zeros((height, width), np.bool_)
    cnt = 0
    fu0, fu1, fv0, fv1 = -radius, radius, -radius, radius
    bu0, bu1, bv0, bv1 = -radius, radius, -radius, radius
    for i in range(n_cur):
        ui = cu_[i]
        vi = cv_[i]
        if use_prior:
            # both stages use the prior of the current feature's cell
            r = prior[_cell(ui, binsize, n_u) * n_v + _cell(vi, binsize, n_v)]
            fu0, fu1, fv0, fv1, bu0, bu1, bv0, bv1 = r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7]
        j = _search(csdesc, crank[i], cc[i], ui + fu0, ui + fu1, vi + fv0, vi + fv1, psu, psv, psdesc, porder,
                    pstart, n_u, n_v, binsize)  # fmt: skip
        uj = pu[j]
        vj = pv[j]
        k = _search(psdesc, prank[j], pc[j], uj + bu0, uj + bu1, vj + bv0, vj + bv1, csu, csv, csdesc, corder,
                    cstart, n_u, n_v, binsize)  # fmt: skip
        if k == i and not occupied[vi, ui]:
            occupied[vi, ui] = True
            out[cnt, 0] = uj
            out[cnt, 1] = vj
            out[cnt, 2] = ui
            out[cnt, 3] = vi
            cnt += 1
    return out[:cnt]


def circle_match(prev: FeatureSet, cur: FeatureSet, grid: Grid, radius: float, prior: np.ndarray | None) -> np.ndarray:
    """Circle-checked matches (M, 4) = (u_prev, v_prev, u_cur, v_cur).

    radius: search half-window without a prior; prior: (n_cells, 8) ranges from `flow_prior`, or None.
    """
    if len(prev) == 0 or len(cur) == 0:
        return np.empty((0, 4), np.int32)
    use_prior = prior is not None
    if prior is None:
        prior = np.zeros((1, 8), np.float64)
    return _circle_match(
        prev.u, prev.v, prev.cls, prev.rank, prev.su, prev.sv, prev.sdesc, prev.order, prev.start,
        cur.u, cur.v, cur.cls, cur.rank, cur.su, cur.sv, cur.sdesc, cur.order, cur.start,
        grid.n_u, grid.n_v, float(grid.binsize), grid.width, grid.height, float(radius), use_prior,
        np.ascontiguousarray(prior, np.float64),
    )  # fmt: skip


def flow_prior(matches: np.ndarray, grid: Grid, radius: float) -> np.ndarray:
    """Per-cell search ranges from (filtered sparse) matches, shape (n_u·n_v, 8), cell index u_cell·n_v + v_cell.

    Columns: fwd u_min, u_max, v_min, v_max (prev − cur, for the search into the previous frame), then bwd
    (cur − prev). Each cell pools the matches whose current-position cell is in its clamped 3×3 neighbourhood;
    ranges narrower than PRIOR_MIN_WIDTH are widened at both ends by ceil((20 − width)/2); empty cells get ±radius.
    """
    n_u, n_v = grid.n_u, grid.n_v
    lo = np.full((n_u, n_v, 2), np.inf)
    hi = np.full((n_u, n_v, 2), -np.inf)
    if len(matches):
        d = (matches[:, 0:2] - matches[:, 2:4]).astype(np.float64)  # fwd delta prev − cur
        mu, mv = grid.cells(matches[:, 2], matches[:, 3])
        for du_cell in (-1, 0, 1):
            for dv_cell in (-1, 0, 1):
                a = mu + du_cell
                b = mv + dv_cell
                ok = (a >= 0) & (a < n_u) & (b >= 0) & (b < n_v)
                for axis in range(2):
                    np.minimum.at(lo[:, :, axis], (a[ok], b[ok]), d[ok, axis])
                    np.maximum.at(hi[:, :, axis], (a[ok], b[ok]), d[ok, axis])
    empty = ~np.isfinite(lo[:, :, 0])
    lo[empty] = 0.0  # temporary finite values for the arithmetic below; empty cells get ±radius after it
    hi[empty] = 0.0
    width = hi - lo
    grow = np.where(width < PRIOR_MIN_WIDTH, np.ceil((PRIOR_MIN_WIDTH - width) / 2), 0.0)
    lo = lo - grow
    hi = hi + grow
    lo[empty] = -radius
    hi[empty] = radius
    prior = np.empty((n_u, n_v, 8))
    prior[:, :, 0], prior[:, :, 1] = lo[:, :, 0], hi[:, :, 0]
    prior[:, :, 2], prior[:, :, 3] = lo[:, :, 1], hi[:, :, 1]
    prior[:, :, 4], prior[:, :, 5] = -hi[:, :, 0], -lo[:, :, 0]  # bwd = −fwd
    prior[:, :, 6], prior[:, :, 7] = -hi[:, :, 1], -lo[:, :, 1]
    return prior.reshape(n_u * n_v, 8)


@njit(cache=True)
def _refine(matches, du_p, dv_p, du_c, dv_c, margin, du_off, dv_off):
    h, w = du_p.shape
    out = matches.copy()
    ref = np.empty(16, np.int32)
    for m in range(len(matches)):
        up, vp, uc, vc = matches[m, 0], matches[m, 1], matches[m, 2], matches[m, 3]
        if up - 2 < margin or up + 2 > w - 1 - margin or vp - 2 < margin or vp + 2 > h - 1 - margin:
            continue  # a shift would come too close to the border: keep the match unrefined
        for b in range(12):
            ref[b] = du_c[vc + du_off[b, 1], uc + du_off[b, 0]]
        for b in range(4):
            ref[12 + b] = dv_c[vc + dv_off[b, 1], uc + dv_off[b, 0]]
        best = 1 << 30
        best_su = 0
        best_sv = 0
        for sv in range(-2, 3):
            for su in range(-2, 3):
                u = up + su
                v = vp + sv
                cost = 0
                for b in range(12):
                    cost += abs(ref[b] - np.int32(du_p[v + du_off[b, 1], u + du_off[b, 0]]))
                for b in range(4):
                    cost += abs(ref[12 + b] - np.int32(dv_p[v + dv_off[b, 1], u + dv_off[b, 0]]))
                if cost < best:
                    best = cost
                    best_su = su
                    best_sv = sv
        out[m, 0] = up + best_su
        out[m, 1] = vp + best_sv
    return out


def refine_integer(matches: np.ndarray, du_prev: np.ndarray, dv_prev: np.ndarray, du_cur: np.ndarray,
                   dv_cur: np.ndarray, margin: int) -> np.ndarray:  # fmt: skip
    """Refinement 1: move each previous-frame position by the ±2 px integer shift minimising the 16-byte SAD."""
    if len(matches) == 0:
        return matches.copy()
    return _refine(np.ascontiguousarray(matches, np.int32), du_prev, dv_prev, du_cur, dv_cur, int(margin),
                   REFINE_DU_OFFSETS, REFINE_DV_OFFSETS)  # fmt: skip
