"""Block non-maximum suppression (Neubeck & Van Gool) on the blob and corner responses (spec §4).

Feature classes: 0 = blob minimum, 1 = blob maximum, 2 = corner minimum, 3 = corner maximum. Features are emitted
block by block (u-blocks outer, v-blocks inner) and, within a block, in class order; the order matters because the
matcher breaks cost ties by feature index.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _window_is_extreme(resp, value, cu, cv, n, u_hi_lim, v_hi_lim, want_max):
    """True when no pixel of the (2n+1)² window around (cu, cv), upper limits clipped, is strictly more extreme."""
    u_hi = min(cu + n, u_hi_lim)
    v_hi = min(cv + n, v_hi_lim)
    for u in range(cu - n, u_hi + 1):
        for v in range(cv - n, v_hi + 1):
            x = resp[v, u]
            if want_max:
                if x > value:
                    return False
            elif x < value:
                return False
    return True


@njit(cache=True)
def _nms(f1, f2, n, margin, tau):
    h, w = f1.shape
    n_bu = max(0, (w - 2 * n - 2 * margin + n) // (n + 1))  # upper bound on blocks, for the output buffers
    n_bv = max(0, (h - 2 * n - 2 * margin + n) // (n + 1))
    cap = 4 * (n_bu + 1) * (n_bv + 1)
    out_u = np.empty(cap, np.int32)
    out_v = np.empty(cap, np.int32)
    out_c = np.empty(cap, np.int8)
    cnt = 0
    u_hi_lim = w - 1 - margin
    v_hi_lim = h - 1 - margin
    cand_u = np.empty(4, np.int64)
    cand_v = np.empty(4, np.int64)
    cand_x = np.empty(4, np.int64)
    u0 = n + margin
    while u0 < w - n - margin:
        v0 = n + margin
        while v0 < h - n - margin:
            # block extremes, u outer / v inner, the first strict extremum wins ties
            for c in range(4):
                resp = f1 if c < 2 else f2
                cand_u[c] = u0
                cand_v[c] = v0
                cand_x[c] = resp[v0, u0]
            for u in range(u0, u0 + n + 1):
                for v in range(v0, v0 + n + 1):
                    a = f1[v, u]
                    b = f2[v, u]
                    if a < cand_x[0]:
                        cand_x[0] = a
                        cand_u[0] = u
                        cand_v[0] = v
                    if a > cand_x[1]:
                        cand_x[1] = a
                        cand_u[1] = u
                        cand_v[1] = v
                    if b < cand_x[2]:
                        cand_x[2] = b
                        cand_u[2] = u
                        cand_v[2] = v
                    if b > cand_x[3]:
                        cand_x[3] = b
                        cand_u[3] = u
                        cand_v[3] = v
            for c in range(4):
                want_max = (c % 2) == 1
                x = cand_x[c]
                if want_max:
                    if x < tau:
                        continue
                elif x > -tau:
                    continue
                resp = f1 if c < 2 else f2
                if _window_is_extreme(resp, x, cand_u[c], cand_v[c], n, u_hi_lim, v_hi_lim, want_max):
                    out_u[cnt] = cand_u[c]
                    out_v[cnt] = cand_v[c]
                    out_c[cnt] = c
                    cnt += 1
            v0 += n + 1
        u0 += n + 1
    return out_u[:cnt], out_v[:cnt], out_c[:cnt]


def block_nms(f1: np.ndarray, f2: np.ndarray, n: int, margin: int, tau: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Features (u, v, class) at the responses' resolution, in libviso2's emission order.

    f1, f2: blob and corner responses (int16, H×W); n: block size parameter; margin: border in pixels;
    tau: a minimum is kept if <= -tau, a maximum if >= tau.
    """
    if f1.shape != f2.shape:
        raise ValueError("f1 and f2 must have the same shape")
    return _nms(np.ascontiguousarray(f1), np.ascontiguousarray(f2), int(n), int(margin), int(tau))
