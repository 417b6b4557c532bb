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


@njit(cache=True)
def _null_vector_8x9(at):
    """Unit null vector of the 8×9 matrix A, given as A^T (9×8, overwritten): last column of Q in A^T = QR."""
    hv = np.zeros((8, 9))
    for k in range(8):
        norm = 0.0
        for i in range(k, 9):
            norm += at[i, k] * at[i, k]
        norm = np.sqrt(norm)
        alpha = -norm if at[k, k] >= 0 else norm
        for i in range(k, 9):
            hv[k, i] = at[i, k]
        hv[k, k] -= alpha
        vv = 0.0
        for i in range(k, 9):
            vv += hv[k, i] * hv[k, i]
        if vv == 0.0:
            continue  # column already zero below the diagonal: identity reflection
        for j in range(k + 1, 8):
            dot = 0.0
            for i in range(k, 9):
                dot += hv[k, i] * at[i, j]
            f = 2.0 * dot / vv
            for i in range(k, 9):
                at[i, j] -= f * hv[k, i]
        for i in range(k, 9):
            hv[k, i] /= np.sqrt(vv)  # store unit vectors
    x = np.zeros(9)
    x[8] = 1.0
    for k in range(7, -1, -1):  # Q e_9 = H_0 (H_1 (… H_7 e_9))
        dot = 0.0
        for i in range(k, 9):
            dot += hv[k, i] * x[i]
        for i in range(k, 9):
            x[i] -= 2.0 * dot * hv[k, i]
    return x


@njit(cache=True)
def _smallest_right_singular_vector_3x3(f):
    """Right singular vector of the smallest singular value of a 3×3 matrix (one-sided Jacobi)."""
    g = f.copy()
    vmat = np.eye(3)
    for _sweep in range(40):
        rotated = False
        for p, q in ((0, 1), (0, 2), (1, 2)):
            alpha = g[0, p] ** 2 + g[1, p] ** 2 + g[2, p] ** 2
            beta = g[0, q] ** 2 + g[1, q] ** 2 + g[2, q] ** 2
            gamma = g[0, p] * g[0, q] + g[1, p] * g[1, q] + g[2, p] * g[2, q]
            if gamma == 0.0 or abs(gamma) <= 1e-15 * np.sqrt(alpha * beta):
                continue
            rotated = True
            zeta = (beta - alpha) / (2.0 * gamma)
            t = (1.0 if zeta >= 0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
            c = 1.0 / np.sqrt(1.0 + t * t)
            s = c * t
            for i in range(3):
                gp, gq = g[i, p], g[i, q]
                g[i, p] = c * gp - s * gq
                g[i, q] = s * gp + c * gq
                vp, vq = vmat[i, p], vmat[i, q]
                vmat[i, p] = c * vp - s * vq
                vmat[i, q] = s * vp + c * vq
        if not rotated:
            break
    k = 0
    best = np.inf
    for j in range(3):
        nrm = g[0, j] ** 2 + g[1, j] ** 2 + g[2, j] ** 2
        if nrm < best:
            best = nrm
            k = j
    return vmat[:, k].copy()


@njit(cache=True)
def fundamental_8point(pu, pv, cu, cv):
    """Rank-2 F (3×3, unit Frobenius norm before rank reduction) with x_curᵀ F x_prev = 0 from exactly 8 matches."""
    at = np.empty((9, 8))
    for r in range(8):
        at[0, r] = cu[r] * pu[r]
        at[1, r] = cu[r] * pv[r]
        at[2, r] = cu[r]
        at[3, r] = cv[r] * pu[r]
        at[4, r] = cv[r] * pv[r]
        at[5, r] = cv[r]
        at[6, r] = pu[r]
        at[7, r] = pv[r]
        at[8, r] = 1.0
    f = _null_vector_8x9(at).reshape(3, 3)
    w = _smallest_right_singular_vector_3x3(f)
    fw = f @ w
    for i in range(3):  # F − σ₃u₃v₃ᵀ = F (I − v₃v₃ᵀ)
        for j in range(3):
            f[i, j] -= fw[i] * w[j]
    return f


@njit(cache=True)
def _count_inliers(f, pu, pv, cu, cv, threshold):
    f0, f1, f2, f3, f4, f5, f6, f7, f8 = f[0, 0], f[0, 1], f[0, 2], f[1, 0], f[1, 1], f[1, 2], f[2, 0], f[2, 1], f[2, 2]
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
    return cnt


@njit(cache=True)
def _ransac(pu, pv, cu, cv, iters, threshold, seed):
    n = len(pu)
    np.random.seed(seed)
    best = 0
    best_f = np.zeros((3, 3))
    idx = np.empty(8, np.int64)
    spu = np.empty(8)
    spv = np.empty(8)
    scu = np.empty(8)
    scv = np.empty(8)
    for _ in range(iters):
        k = 0
        while k < 8:  # 8 distinct indices
            r = np.random.randint(0, n)
            dup = False
            for q in range(k):
                if idx[q] == r:
                    dup = True
                    break
            if not dup:
                idx[k] = r
                k += 1
        for q in range(8):
            spu[q] = pu[idx[q]]
            spv[q] = pv[idx[q]]
            scu[q] = cu[idx[q]]
            scv[q] = cv[idx[q]]
        f = fundamental_8point(spu, spv, scu, scv)
        cnt = _count_inliers(f, pu, pv, cu, cv, threshold)
        if cnt > best:
            best = cnt
            best_f[:, :] = f
    return best, best_f


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
    count, f_norm = _ransac(pu, pv, cu, cv, int(iters), float(threshold), _numba_seed(seed))
    mask = _inlier_mask(f_norm, pu, pv, cu, cv, threshold)
    f_pix = tc.T @ f_norm @ tp
    return int(count), f_pix, mask


def ransac_inlier_count(matches: np.ndarray, iters: int, threshold: float, seed: int) -> int:
    """Best F-RANSAC consensus size (libviso2's getNumberOfInliers for mono)."""
    m = np.asarray(matches, np.float64)
    if len(m) < MIN_MATCHES:
        return 0
    pu, pv, _ = hartley_normalise(m[:, 0], m[:, 1])
    cu, cv, _ = hartley_normalise(m[:, 2], m[:, 3])
    return int(_ransac(pu, pv, cu, cv, int(iters), float(threshold), _numba_seed(seed))[0])


def _inlier_mask(f, pu, pv, cu, cv, threshold) -> np.ndarray:
    xp = np.stack([pu, pv, np.ones_like(pu)])
    xc = np.stack([cu, cv, np.ones_like(cu)])
    fxp = f @ xp
    ftxc = f.T @ xc
    num = (xc * fxp).sum(axis=0)
    return num * num < threshold * (fxp[0] ** 2 + fxp[1] ** 2 + ftxc[0] ** 2 + ftxc[1] ** 2)


def _numba_seed(seed: int) -> int:
    # numba's np.random.seed takes an unsigned 32-bit value; any int (negative too) maps to one
    return int(np.random.SeedSequence(int(seed) % 2**64).generate_state(1)[0])


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
