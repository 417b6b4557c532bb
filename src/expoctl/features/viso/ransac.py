"""Monocular fundamental-matrix RANSAC and bucketing of the libviso2-style matcher (spec §8).

Hartley normalisation per frame, 8-point F from 8 distinct random matches (null vector of the 8×9 system, rank 2
enforced by zeroing the smallest singular value), Sampson error below `threshold` in normalised coordinates, and a
model replaces the best only with a strictly larger consensus. The count is that best consensus size.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: libviso2 refuses to estimate motion from fewer matches than this (and then reports 0 inliers).
MIN_MATCHES = 10


def hartley_normalise(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normalised (u, v) with centroid 0 and mean distance √2 from it, and the 3×3 transform T (x_n = T x)."""
    cu, cv = u.mean(), v.mean()
    mean_dist = np.hypot(u - cu, v - cv).mean()
    s = np.sqrt(2.0) / mean_dist if mean_dist > 0 else 1.0
    t = np.array([[s, 0, -s * cu], [0, s, -s * cv], [0, 0, 1.0]])
    return s * (u - cu), s * (v - cv), t


@njit(cache=True, error_model="numpy")
def _models_8point(pu, pv, cu, cv, idx):
    """One rank-2 F per row of idx (8 match indices each); written as a single function so numba compiles it once.

    Null vector of the 8×9 system A f = 0 as the last column of Q in the Householder QR of Aᵀ (9×8); rank 2 by
    F ← F (I − v vᵀ), v the right singular vector of the smallest singular value (one-sided Jacobi on F's columns).
    """
    n_models = idx.shape[0]
    out = np.empty((n_models, 3, 3))
    at = np.empty((9, 8))
    hv = np.empty((8, 9))
    x = np.empty(9)
    g = np.empty((3, 3))
    vm = np.empty((3, 3))
    for m in range(n_models):
        for r in range(8):
            k = idx[m, r]
            up, vp, uc, vc = pu[k], pv[k], cu[k], cv[k]
            at[0, r] = uc * up
            at[1, r] = uc * vp
            at[2, r] = uc
            at[3, r] = vc * up
            at[4, r] = vc * vp
            at[5, r] = vc
            at[6, r] = up
            at[7, r] = vp
            at[8, r] = 1.0
        # Householder QR of Aᵀ; hv[k] holds the unit reflection vector of step k (zero: identity)
        for k in range(8):
            norm = 0.0
            for i in range(k, 9):
                norm += at[i, k] * at[i, k]
            norm = np.sqrt(norm)
            alpha = -norm if at[k, k] >= 0 else norm
            vv = 0.0
            for i in range(9):
                hv[k, i] = at[i, k] if i >= k else 0.0
            hv[k, k] -= alpha
            for i in range(k, 9):
                vv += hv[k, i] * hv[k, i]
            if vv == 0.0:
                continue
            inv = 1.0 / np.sqrt(vv)
            for i in range(k, 9):
                hv[k, i] *= inv
            for j in range(k + 1, 8):
                dot = 0.0
                for i in range(k, 9):
                    dot += hv[k, i] * at[i, j]
                for i in range(k, 9):
                    at[i, j] -= 2.0 * dot * hv[k, i]
        for i in range(9):
            x[i] = 0.0
        x[8] = 1.0
        for k in range(7, -1, -1):  # Q e₉ = H₀ (H₁ (… H₇ e₉))
            dot = 0.0
            for i in range(k, 9):
                dot += hv[k, i] * x[i]
            for i in range(k, 9):
                x[i] -= 2.0 * dot * hv[k, i]
        # one-sided Jacobi on the columns of F: the column of V with the smallest final norm is v
        for i in range(3):
            for j in range(3):
                g[i, j] = x[3 * i + j]
                vm[i, j] = 1.0 if i == j else 0.0
        for _sweep in range(40):
            rotated = False
            for pair in range(3):
                p = 0 if pair < 2 else 1  # column pairs (0, 1), (0, 2), (1, 2)
                q = 1 if pair == 0 else 2
                al = g[0, p] * g[0, p] + g[1, p] * g[1, p] + g[2, p] * g[2, p]
                be = g[0, q] * g[0, q] + g[1, q] * g[1, q] + g[2, q] * g[2, q]
                ga = g[0, p] * g[0, q] + g[1, p] * g[1, q] + g[2, p] * g[2, q]
                if ga == 0.0 or abs(ga) <= 1e-15 * np.sqrt(al * be):
                    continue
                rotated = True
                zeta = (be - al) / (2.0 * ga)
                t = (1.0 if zeta >= 0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = c * t
                for i in range(3):
                    gp, gq = g[i, p], g[i, q]
                    g[i, p] = c * gp - s * gq
                    g[i, q] = s * gp + c * gq
                    vp_, vq_ = vm[i, p], vm[i, q]
                    vm[i, p] = c * vp_ - s * vq_
                    vm[i, q] = s * vp_ + c * vq_
            if not rotated:
                break
        kmin = 0
        best = np.inf
        for j in range(3):
            nrm = g[0, j] * g[0, j] + g[1, j] * g[1, j] + g[2, j] * g[2, j]
            if nrm < best:
                best = nrm
                kmin = j
        w0, w1, w2 = vm[0, kmin], vm[1, kmin], vm[2, kmin]
        for i in range(3):  # F − σ₃u₃v₃ᵀ = F (I − v₃v₃ᵀ)
            fw = x[3 * i] * w0 + x[3 * i + 1] * w1 + x[3 * i + 2] * w2
            out[m, i, 0] = x[3 * i] - fw * w0
            out[m, i, 1] = x[3 * i + 1] - fw * w1
            out[m, i, 2] = x[3 * i + 2] - fw * w2
    return out


def fundamental_8point(pu, pv, cu, cv) -> np.ndarray:
    """Rank-2 F (3×3) with x_curᵀ F x_prev = 0 from exactly 8 matches (unit norm before the rank reduction)."""
    idx = np.arange(8, dtype=np.int64)[None, :]
    return _models_8point(*(np.ascontiguousarray(a, np.float64) for a in (pu, pv, cu, cv)), idx)[0]


@njit(cache=True, error_model="numpy")
def _best_consensus(models, pu, pv, cu, cv, threshold):
    """(size, index) of the first model with the largest Sampson consensus; a later model must be strictly larger."""
    best = 0
    best_m = -1
    for m in range(models.shape[0]):
        f0, f1, f2 = models[m, 0, 0], models[m, 0, 1], models[m, 0, 2]
        f3, f4, f5 = models[m, 1, 0], models[m, 1, 1], models[m, 1, 2]
        f6, f7, f8 = models[m, 2, 0], models[m, 2, 1], models[m, 2, 2]
        cnt = 0
        for i in range(len(pu)):
            x, y, xc, yc = pu[i], pv[i], cu[i], cv[i]
            a0 = f0 * x + f1 * y + f2  # F x_prev
            a1 = f3 * x + f4 * y + f5
            a2 = f6 * x + f7 * y + f8
            b0 = f0 * xc + f3 * yc + f6  # Fᵀ x_cur
            b1 = f1 * xc + f4 * yc + f7
            num = xc * a0 + yc * a1 + a2
            # Sampson error num² / den < threshold, without the division (den = 0 is never an inlier)
            if num * num < threshold * (a0 * a0 + a1 * a1 + b0 * b0 + b1 * b1):
                cnt += 1
        if cnt > best:
            best = cnt
            best_m = m
    return best, best_m


def draw_samples(n: int, iters: int, rng: np.random.Generator) -> np.ndarray:
    """(iters, 8) indices into n >= 8 matches, 8 distinct per row, uniformly over 8-subsets (in random order)."""
    if n <= 64:
        return np.argsort(rng.random((iters, n)), axis=1)[:, :8].astype(np.int64)
    idx = rng.integers(0, n, (iters, 8))
    while True:  # redraw the rows that repeat an index (a few % of rows for n in the hundreds)
        srt = np.sort(idx, axis=1)
        bad = (srt[:, 1:] == srt[:, :-1]).any(axis=1)
        if not bad.any():
            return idx
        idx[bad] = rng.integers(0, n, (int(bad.sum()), 8))


def _ransac(pu, pv, cu, cv, iters: int, threshold: float, seed: int) -> tuple[int, np.ndarray | None]:
    rng = np.random.default_rng(int(seed) % 2**64)
    models = _models_8point(pu, pv, cu, cv, draw_samples(len(pu), iters, rng))
    best, m = _best_consensus(models, pu, pv, cu, cv, float(threshold))
    return int(best), (models[m] if m >= 0 else None)


def ransac_fundamental(matches: np.ndarray, iters: int, threshold: float, seed: int):
    """F-RANSAC on matches (u_prev, v_prev, u_cur, v_cur): (best consensus size, F in pixel coordinates, inlier mask).

    Fewer than MIN_MATCHES matches give (0, None, all-False), as libviso2's fresh object reports 0 inliers.
    """
    m = np.asarray(matches, np.float64)
    n = len(m)
    if n < MIN_MATCHES:
        return 0, None, np.zeros(n, bool)
    pu, pv, tp = hartley_normalise(m[:, 0], m[:, 1])
    cu, cv, tc = hartley_normalise(m[:, 2], m[:, 3])
    count, f_norm = _ransac(pu, pv, cu, cv, int(iters), threshold, seed)
    if f_norm is None:
        return 0, None, np.zeros(n, bool)
    mask = _inlier_mask(f_norm, pu, pv, cu, cv, threshold)
    return count, tc.T @ f_norm @ tp, mask


def ransac_inlier_count(matches: np.ndarray, iters: int, threshold: float, seed: int) -> int:
    """Best F-RANSAC consensus size (libviso2's getNumberOfInliers for mono)."""
    m = np.asarray(matches, np.float64)
    if len(m) < MIN_MATCHES:
        return 0
    pu, pv, _ = hartley_normalise(m[:, 0], m[:, 1])
    cu, cv, _ = hartley_normalise(m[:, 2], m[:, 3])
    return _ransac(pu, pv, cu, cv, int(iters), threshold, seed)[0]


def _inlier_mask(f, pu, pv, cu, cv, threshold) -> np.ndarray:
    xp = np.stack([pu, pv, np.ones_like(pu)])
    xc = np.stack([cu, cv, np.ones_like(cu)])
    fxp = f @ xp
    ftxc = f.T @ xc
    num = (xc * fxp).sum(axis=0)
    return num * num < threshold * (fxp[0] ** 2 + fxp[1] ** 2 + ftxc[0] ** 2 + ftxc[1] ** 2)


def bucket(matches: np.ndarray, max_features: int, width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """Keep at most `max_features` random matches per width×height cell of the current position (libviso2's
    bucketFeatures); the number kept is Σ min(n_cell, max_features) whatever the draw."""
    if len(matches) == 0:
        return matches
    col = matches[:, 2] // width
    row = matches[:, 3] // height
    n_cols = int(col.max()) + 1
    cell = row.astype(np.int64) * n_cols + col
    perm = rng.permutation(len(matches))  # a random order inside every cell …
    perm = perm[np.argsort(cell[perm], kind="stable")]  # … grouped by cell
    sorted_cell = cell[perm]
    first = np.searchsorted(sorted_cell, sorted_cell, side="left")
    rank = np.arange(len(perm)) - first
    return matches[np.sort(perm[rank < max_features])]
