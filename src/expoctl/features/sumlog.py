"""SumLog illumination-invariant transform (Clement et al. 2020, used in the paper's SL experiments).

    SumLog(I) = Σ_c α_c · log(I_c + β)        c ∈ {R, G, B}, I_c in 8-bit digital numbers (DN)

A global gain k (exposure or analogue gain change) multiplies every I_c; with β = 0 it only adds the constant
(Σ_c α_c)·log k, so the image *structure* (all differences between pixels) is unchanged. β > 0 keeps log finite at
black and limits the amplification of dark-pixel noise, at the price of exact invariance in the darks.

Rescaling to 8 bits for the front ends ("range" mode, the default): a FIXED affine map of the transform's whole
attainable range over 8-bit inputs, [lo, hi] with lo = Σ_c min(α_c·log β, α_c·log(255+β)) and hi the matching
max, onto 0…255 (rounded, clipped). Being image-independent it maps the same RGB to the same grey in every frame, so
consecutive frames stay comparable and a global gain change shows up only as an offset (which FAST/ORB ignore).
"minmax" mode stretches each image's own min…max instead (maximal contrast, but the mapping changes per frame).

`tune_sumlog` picks α and β from a grid by maximising the total inlier matches between sequential training pairs
(the paper: "selecting the parameter values that yielded the maximum number of feature matches between sequential
image pairs").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from expoctl.config_reader import Problems, Section
from expoctl.errors import ConfigError

RESCALE_MODES = ("range", "minmax")


@dataclass(frozen=True)
class SumLogParams:
    alpha: tuple[float, float, float] = (1 / 3, 1 / 3, 1 / 3)  # weights of log R, log G, log B
    beta: float = 1.0  # offset in DN added before the log
    rescale: str = "range"  # how the float result becomes 8-bit: range | minmax (see module docstring)

    def __post_init__(self):
        alpha = tuple(float(a) for a in self.alpha) if _is_seq(self.alpha) else ()
        if len(alpha) != 3 or not all(math.isfinite(a) for a in alpha) or not any(alpha):
            raise ConfigError("features.sumlog.alpha", f"must be 3 finite numbers, not all 0; got {self.alpha!r}")
        object.__setattr__(self, "alpha", alpha)
        if not (isinstance(self.beta, (int, float)) and math.isfinite(self.beta) and self.beta >= 0):
            raise ConfigError("features.sumlog.beta", f"must be a finite number >= 0, got {self.beta!r}")
        object.__setattr__(self, "beta", float(self.beta))
        if self.rescale not in RESCALE_MODES:
            raise ConfigError("features.sumlog.rescale", f"must be one of {RESCALE_MODES}, got {self.rescale!r}")


def _is_seq(v) -> bool:
    return isinstance(v, (list, tuple, np.ndarray))


def sumlog(rgb: np.ndarray, alpha: Sequence[float], beta: float) -> np.ndarray:
    """Σ_c α_c·log(I_c + β) per pixel, float64 H×W. `rgb` is H×W×3 (uint8 DN or float, same scale as β)."""
    img = np.asarray(rgb)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"SumLog needs an H×W×3 RGB image, got shape {img.shape}")
    shifted = img.astype(np.float64) + float(beta)
    if np.any(shifted <= 0):
        raise ValueError(f"SumLog: I + β must be > 0 everywhere (β = {beta}); use β > 0 for images with black pixels")
    logs = np.log(shifted)
    return logs @ np.asarray(alpha, dtype=np.float64)


def sumlog_range(alpha: Sequence[float], beta: float, max_dn: float = 255.0) -> tuple[float, float]:
    """(lo, hi): the smallest and largest SumLog values any image with channels in [0, max_dn] can produce."""
    if beta <= 0:
        raise ValueError("the 8-bit range of SumLog is unbounded for β = 0 (log 0); use β > 0 with rescale 'range'")
    ends = np.array([[a * math.log(beta), a * math.log(max_dn + beta)] for a in alpha])
    return float(ends.min(axis=1).sum()), float(ends.max(axis=1).sum())


def sumlog_uint8(rgb: np.ndarray, params: SumLogParams) -> np.ndarray:
    """SumLog rescaled to an 8-bit grey image the front ends take (see module docstring for the two modes)."""
    s = sumlog(rgb, params.alpha, params.beta)
    if params.rescale == "range":
        lo, hi = sumlog_range(params.alpha, params.beta)
    else:
        lo, hi = float(s.min()), float(s.max())
    if hi <= lo:  # a constant image in minmax mode: no structure to show
        return np.zeros(s.shape, np.uint8)
    return np.clip(np.rint((s - lo) * (255.0 / (hi - lo))), 0, 255).astype(np.uint8)


def score_sumlog_grid(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    frontend,
    alphas: Iterable[Sequence[float]],
    betas: Iterable[float],
    rescale: str = "range",
    seed: int = 0,
) -> list[tuple[SumLogParams, int]]:
    """Total inlier matches over `pairs` (prev RGB, cur RGB) for every (α, β) in the grid, in grid order (α outer)."""
    if len(pairs) == 0:
        raise ValueError("SumLog tuning needs at least one training pair")
    grid = [SumLogParams(tuple(a), b, rescale) for a in alphas for b in betas]
    if not grid:
        raise ConfigError("features.sumlog.alphas", "the tuning grid is empty (need at least one alpha and one beta)")
    results = []
    for params in grid:
        cache: dict[int, object] = {}  # consecutive pairs share images: extract each array once per grid point

        def extracted(img):
            if id(img) not in cache:
                cache[id(img)] = frontend.extract(sumlog_uint8(img, params))
            return cache[id(img)]

        total = 0
        for k, (prev, cur) in enumerate(pairs):
            total += int(frontend.match(extracted(prev), extracted(cur), seed + k)[1])
        results.append((params, total))
    return results


def tune_sumlog(
    pairs: Sequence[tuple[np.ndarray, np.ndarray]],
    frontend,
    alphas: Iterable[Sequence[float]],
    betas: Iterable[float],
    rescale: str = "range",
    seed: int = 0,
) -> SumLogParams:
    """The grid point with the most inlier matches over the training pairs; ties go to the earliest in grid order."""
    scored = score_sumlog_grid(pairs, frontend, alphas, betas, rescale, seed)
    best_total = max(total for _, total in scored)
    return next(params for params, total in scored if total == best_total)


@dataclass(frozen=True)
class SumLogGrid:
    """The `features.sumlog` config: the tuning grid and how many sequential training pairs to tune on."""

    alphas: tuple[tuple[float, float, float], ...] = ((1 / 3, 1 / 3, 1 / 3),)
    betas: tuple[float, ...] = (1.0,)
    rescale: str = "range"
    max_pairs: int = 100

    @classmethod
    def from_dict(cls, d: dict | None, key: str = "features.sumlog", problems: Problems | None = None) -> "SumLogGrid":
        r = Section(d, key, problems)
        alphas = r.value("alphas", cls.alphas)
        if not _is_seq(alphas) or len(alphas) == 0:
            r.problem("alphas", f"must be a non-empty list of [α_R, α_G, α_B], got {alphas!r}")
            alphas = cls.alphas
        betas = r.value("betas", cls.betas)
        if not _is_seq(betas) or len(betas) == 0:
            r.problem("betas", f"must be a non-empty list of numbers, got {betas!r}")
            betas = cls.betas
        rescale = r.value("rescale", cls.rescale)
        max_pairs = r.integer("max_pairs", cls.max_pairs, min=1)
        try:
            params = [SumLogParams(a, b, rescale) for a in alphas for b in betas]  # validates every grid point
        except ConfigError as exc:  # name the grid's key (alphas/betas), not the single point's (alpha/beta)
            r.problem({"alpha": "alphas", "beta": "betas"}.get(exc.key.rsplit(".", 1)[-1], "rescale"), exc.problem)
            params = []
        if rescale == "range" and any(p.beta <= 0 for p in params):
            r.problem("betas", "must all be > 0 with rescale 'range' (log 0 is unbounded)")
        r.done()
        if not params:  # a bad grid point: reported above, raised by the outermost section
            return cls()
        return cls(tuple(tuple(float(v) for v in a) for a in alphas), tuple(float(b) for b in betas), rescale, max_pairs)
