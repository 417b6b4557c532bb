"""Image metrics shared by the baseline controllers (docs/controllers.md, Image metrics).

Every function takes an 8-bit image (H×W×3 RGB or H×W grey) or a float array and returns finite numbers for any
input, including all-black and all-saturated frames: controllers must never emit NaN.

Conventions
- "grey" is the plain mean of the R, G, B channels as float64 on the 0–255 scale (Shin's MATLAB averages the channels;
  see docs/controllers.md, Shin et al. 2019).
- "linear" values are on [0, 1] of full scale, i.e. after inverting the camera response
  (`expoctl.camera.response`).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

ResponseInverse = Callable[[np.ndarray], np.ndarray]


# ------------------------------------------------------------------------------------------------------ metering
#: fraction of the frame area metered by the FLIR modes (Spinnaker docs: spot ≈ 3 %, partial ≈ 11 %, centred)
METERING_AREA_FRACTION = {"average": 1.0, "spot": 0.03, "partial": 0.11}


def metering_window(shape: tuple[int, ...], mode: str = "average", roi=None) -> tuple[slice, slice]:
    """Row/column slices of the metered region. `roi` = (x0, y0, x1, y1) as fractions of width/height overrides
    `mode` (the camera's AasRoi). Spot/partial are centred squares-in-proportion covering the mode's area fraction."""
    h, w = int(shape[0]), int(shape[1])
    if roi is not None:
        x0, y0, x1, y1 = (float(v) for v in roi)
        r0, r1 = int(np.floor(y0 * h)), int(np.ceil(y1 * h))
        c0, c1 = int(np.floor(x0 * w)), int(np.ceil(x1 * w))
    else:
        side = np.sqrt(METERING_AREA_FRACTION[mode])  # same fraction of each dimension keeps the frame's aspect
        rh, rw = max(1, int(round(h * side))), max(1, int(round(w * side)))
        r0, c0 = (h - rh) // 2, (w - rw) // 2
        r1, c1 = r0 + rh, c0 + rw
    r0, c0 = max(0, min(r0, h - 1)), max(0, min(c0, w - 1))
    return slice(r0, max(r0 + 1, min(r1, h))), slice(c0, max(c0 + 1, min(c1, w)))


def metered_linear_mean(img: np.ndarray, response_inverse: ResponseInverse, mode: str = "average", roi=None) -> float:
    """Mean of the linear image (channels averaged) over the metering region, in [0, 1] of full scale."""
    rows, cols = metering_window(img.shape, mode, roi)
    lin = np.asarray(response_inverse(np.asarray(img)[rows, cols]), dtype=np.float64)
    m = float(np.mean(lin))
    return m if np.isfinite(m) else 0.0


def grey(img: np.ndarray) -> np.ndarray:
    """Channel mean on the 0–255 scale as float64 (H×W)."""
    a = np.asarray(img, dtype=np.float64)
    return a.mean(axis=2) if a.ndim == 3 else a


def luma_uint8(img: np.ndarray) -> np.ndarray:
    """8-bit luma with MATLAB rgb2gray's Rec.601 weights (0.299, 0.587, 0.114), rounded; grey input is passed on."""
    a = np.asarray(img)
    if a.ndim == 2:
        return a.astype(np.uint8, copy=False)
    # OpenCV's fixed-point RGB→grey uses the same weights (0.299, 0.587, 0.114) with rounding
    return cv2.cvtColor(np.ascontiguousarray(a, dtype=np.uint8), cv2.COLOR_RGB2GRAY)


# ------------------------------------------------------------------------------------------------------ gradients
#: Sobel magnitude of a 0/255 step along both axes: |gx| = |gy| = 4·255 → the normaliser maps magnitudes into [0, 1]
SOBEL_MAX_MAGNITUDE = float(np.sqrt(2.0 * (4.0 * 255.0) ** 2))


def sobel_magnitude(grey_0_255: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude (3×3, replicated border) of a 0–255 image, float64."""
    # float32 is exact for 8-bit input (|gx|, |gy| ≤ 1020 are small integers) and halves the memory traffic
    g = np.asarray(grey_0_255, dtype=np.float32)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    return cv2.magnitude(gx, gy).astype(np.float64)


def normalised_gradient(grey_0_255: np.ndarray) -> np.ndarray:
    """Sobel magnitude divided by √(2·(4·255)²), in [0, 1] (Shin's MATLAB normalisation)."""
    return sobel_magnitude(grey_0_255) / SOBEL_MAX_MAGNITUDE


def shim_map(m: np.ndarray, lam: float = 1e3, delta: float = 0.06) -> np.ndarray:
    """Shim et al. 2014 gradient mapping: log(λ(m−δ)+1)/log(λ(1−δ)+1) for m ≥ δ, else 0. Maps [δ, 1] onto [0, 1],
    suppressing gradients below δ (noise) and compressing strong ones (λ)."""
    m = np.asarray(m, dtype=np.float64)
    out = np.log(lam * np.maximum(m - delta, 0.0) + 1.0) / np.log(lam * (1.0 - delta) + 1.0)
    return np.where(m >= delta, out, 0.0)


def shim_gradient_information(grey_0_255: np.ndarray, lam: float = 1e3, delta: float = 0.06) -> float:
    """Shim's total gradient information M, as the per-pixel *mean* of the mapped gradient (Shim sums; the mean
    only rescales by the pixel count and keeps values comparable across resolutions)."""
    return float(np.mean(shim_map(normalised_gradient(grey_0_255), lam, delta)))


def cell_means(a: np.ndarray, n_cells: int) -> np.ndarray:
    """Means of an n×n grid of near-equal cells (integer bounds, every pixel in exactly one cell)."""
    h, w = a.shape
    rb = np.linspace(0, h, n_cells + 1).round().astype(int)
    cb = np.linspace(0, w, n_cells + 1).round().astype(int)
    return np.array([[a[rb[i] : rb[i + 1], cb[j] : cb[j + 1]].mean() for j in range(n_cells)] for i in range(n_cells)])


def shin_gradient_term(
    grey_0_255: np.ndarray, lam: float = 1e3, delta: float = 0.06, n_cells: int = 10, max_value: float = 10.0
) -> float:
    """Shin et al. 2019 gradient term G = mean/std (sample std, N−1) of the n×n cell means of the Shim-mapped
    gradient: rewards gradient spread evenly over the frame. NaN-free guards (ours): no gradient at all → 0;
    perfectly even gradient (std 0) or a ratio above `max_value` → `max_value` (the C++ port's cap of 10)."""
    cells = cell_means(shim_map(normalised_gradient(grey_0_255), lam, delta), n_cells).ravel()
    mean = float(cells.mean())
    if mean <= 0.0:
        return 0.0
    std = float(cells.std(ddof=1)) if cells.size > 1 else 0.0
    if std <= mean / max_value:
        return float(max_value)
    return mean / std


# ------------------------------------------------------------------------------------------------ entropy, noise
def entropy_bits(grey_uint8: np.ndarray) -> float:
    """Shannon entropy (bits) of the 256-bin histogram of an 8-bit image; 0 for a constant image, 8 at most."""
    hist = np.bincount(np.asarray(grey_uint8, dtype=np.uint8).ravel(), minlength=256).astype(np.float64)
    p = hist[hist > 0] / hist.sum()
    return float(-(p * np.log2(p)).sum()) + 0.0  # + 0.0 turns -0.0 into 0.0


#: Immerkær's kernel: the difference of two Laplacians; zero response to any locally planar image
IMMERKAER_KERNEL = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])


def immerkaer_sigma(
    channel_0_255: np.ndarray,
    homogeneous_fraction: float = 0.10,
    intensity_range: tuple[float, float] = (15.0, 235.0),
    min_mask_fraction: float = 1e-4,
) -> float:
    """Noise standard deviation (0–255 units) of one channel by Immerkær's estimator
    σ = √(π/2)·Σ|I∗L|/(6·N_s), over the "homogeneous" pixels: the `homogeneous_fraction` with the lowest squared
    Sobel gradient, restricted to `intensity_range` (Shin 2019). Falls back to all interior pixels when fewer than
    `min_mask_fraction` of the pixels qualify. `homogeneous_fraction=1` with the full range gives Immerkær's
    original whole-image estimator. (A 1×1 or 2×2 image returns 0.)"""
    img = np.asarray(channel_0_255, dtype=np.float64)
    h, w = img.shape
    if h < 3 or w < 3:
        return 0.0
    lap = cv2.filter2D(img, cv2.CV_64F, IMMERKAER_KERNEL, borderType=cv2.BORDER_REPLICATE)
    interior = np.zeros((h, w), bool)
    interior[1:-1, 1:-1] = True  # border responses come from padding, not from the image
    grad2 = sobel_magnitude(img) ** 2
    k = max(1, int(np.ceil(homogeneous_fraction * h * w)))
    threshold = np.partition(grad2.ravel(), k - 1)[k - 1] if k < h * w else np.inf
    lo, hi = intensity_range
    mask = (grad2 <= threshold) & (img >= lo) & (img <= hi) & interior
    if mask.sum() < min_mask_fraction * h * w or not mask.any():
        mask = interior
    return float(np.sqrt(np.pi / 2.0) * np.abs(lap[mask]).sum() / (6.0 * mask.sum()))


def shin_noise_term(img: np.ndarray, **kwargs) -> float:
    """Shin's N: Immerkær σ per channel, averaged over channels (the MATLAB colour branch always takes this path)."""
    a = np.asarray(img)
    chans = [a[..., c] for c in range(a.shape[2])] if a.ndim == 3 else [a]
    return float(np.mean([immerkaer_sigma(c, **kwargs) for c in chans]))


def shin_score(
    img: np.ndarray,
    alpha: float = 0.4,
    k_g: float = 2.0,
    beta: float = 0.4,
    lam: float = 1e3,
    delta: float = 0.06,
    n_cells: int = 10,
) -> tuple[float, float, float, float]:
    """Shin et al. 2019 score α·K_g·G + (1−α)·E − β·N (MATLAB constants) and its terms (score, G, E, N).
    G and E use the rgb2gray luma, N the per-channel average, all on the 0–255 scale."""
    y = luma_uint8(img)
    g_term = shin_gradient_term(y, lam, delta, n_cells)
    e_term = entropy_bits(y) / 8.0
    n_term = shin_noise_term(img)
    return alpha * k_g * g_term + (1.0 - alpha) * e_term - beta * n_term, g_term, e_term, n_term
