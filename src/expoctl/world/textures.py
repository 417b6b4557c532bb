"""Albedo textures: real photographs (scikit-image's brick, gravel and grass) mixed with procedural detail.

Each material gets one square, wrap-around tile (`tile_px`² texels of `texel_m` metres) holding *relative* albedo
(mean 1 over the tile; the city's mean albedo per material scales it in the shader). Tiles carry broadband detail
(1/f noise at several octaves, photo grain), man-made structure (panel joints, windows, cable trays, signs, posters,
stains) and are stored with a full box-filtered mip pyramid so the shader can pick the level matching the projected
pixel footprint (no aliasing flicker). The renderer additionally shifts the tile by a random offset per tile-length
cell along the route, so no two neighbouring cells repeat with a fixed period.

Cities never share a tile: each city uses its own texture seed and a disjoint half (`photo_crop` 'a' = left half,
'b' = right half) of every photograph.
"""

from __future__ import annotations

import numpy as np
import skimage.data
import skimage.transform

from expoctl.world.cities import MATERIALS

# physical size of one pixel of the scikit-image photographs (judged from brick courses ~7.5 cm and stone sizes)
_PHOTO_TEXEL_M = {"brick": 0.004, "gravel": 0.0025, "grass": 0.003}


def _noise(rng: np.random.Generator, n: int, beta: float, min_period_px: float = 2.0, max_period_px: float | None = None):
    """Periodic (tileable) noise with a 1/f^beta amplitude spectrum, zero mean and unit std."""
    fy = np.fft.fftfreq(n).astype(np.float32)
    fx = np.fft.rfftfreq(n).astype(np.float32)
    f = np.sqrt(fy[:, None] ** 2 + fx[None, :] ** 2)
    band = (f >= (1.0 / max_period_px if max_period_px else 0.0)) & (f <= 1.0 / min_period_px) & (f > 0)
    amp = np.zeros_like(f)
    amp[band] = f[band] ** (-beta)
    phase = rng.uniform(0, 2 * np.pi, f.shape).astype(np.float32)
    img = np.fft.irfft2(amp * (np.cos(phase) + 1j * np.sin(phase)), s=(n, n))
    return ((img - img.mean()) / (img.std() + 1e-12)).astype(np.float32)


def _photo(name: str, crop: str, n: int, texel_m: float, rng: np.random.Generator, scale: float = 1.0):
    """A tileable n×n layer from half of a scikit-image photograph at its physical scale (mean 0, std 1)."""
    img = getattr(skimage.data, name)().astype(np.float32)
    half = img[:, : img.shape[1] // 2] if crop == "a" else img[:, img.shape[1] // 2:]
    if rng.random() < 0.5:
        half = half[::-1]
    tile = np.concatenate([half, half[:, ::-1]], axis=1)  # mirror: seamless horizontally
    tile = np.concatenate([tile, tile[::-1]], axis=0)  # and vertically
    zoom = _PHOTO_TEXEL_M[name] * scale / texel_m
    size = max(8, int(round(tile.shape[0] * zoom)))
    tile = skimage.transform.resize(tile, (size, size), anti_aliasing=zoom < 1, preserve_range=True)
    reps = int(np.ceil(n / size)) + 1
    big = np.tile(tile, (reps, reps))
    oy, ox = rng.integers(0, size, 2)
    out = big[oy:oy + n, ox:ox + n]
    # photos are not tileable at arbitrary n: blend the wrap seam over 16 texels
    return ((out - out.mean()) / (out.std() + 1e-6)).astype(np.float32)


def _rects(rng, img, n_rect, w_px, h_px, y_px, value_fn):
    """Paint random rectangles (signs, posters) with values from value_fn(h, w)."""
    n = img.shape[0]
    for _ in range(n_rect):
        w = int(rng.uniform(*w_px))
        h = int(rng.uniform(*h_px))
        x0 = int(rng.integers(0, n))
        y0 = int(rng.uniform(*y_px))
        ys = np.arange(y0, y0 + h) % n
        xs = np.arange(x0, x0 + w) % n
        img[np.ix_(ys, xs)] = value_fn(h, w)


def _poster(rng, channels):
    def fill(h, w):
        base = rng.uniform(0.2, 1.8, size=3) if channels else np.full(3, rng.uniform(0.3, 1.8))
        out = np.ones((h, w, 3), np.float32) * base
        # text-like blocks: rows of dark dashes
        rows = max(1, h // 30)
        for r in range(rows):
            y = int((r + 0.5) * h / rows)
            xs = np.cumsum(rng.integers(6, 30, size=w // 6 + 2))
            for a, b in zip(xs[::2], xs[1::2]):
                if b < w - 2 and rng.random() < 0.35:
                    out[max(0, y - 2):y + 2, a:b] *= rng.uniform(0.1, 0.5)
        out[:2], out[-2:], out[:, :2], out[:, -2:] = 0.25, 0.25, 0.25, 0.25  # frame
        return out
    return fill


def _joints(img, positions_px, axis, width_px, depth):
    n = img.shape[0]
    for p in positions_px:
        idx = (np.arange(int(p), int(p) + width_px)) % n
        if axis == 1:
            img[:, idx] *= depth
        else:
            img[idx, :] *= depth


def _random_cuts(rng, n, lo_px, hi_px):
    cuts, x = [], 0.0
    while x < n - lo_px:
        cuts.append(x)
        x += rng.uniform(lo_px, hi_px)
    return cuts


def make_material(kind: str, n: int, texel_m: float, crop: str, rng: np.random.Generator) -> np.ndarray:
    """Relative albedo tile (n, n, 3) float32, mean ≈ 1. Row index = height (walls) or lateral (ground) / texel_m."""
    m = 1.0 / texel_m  # texels per metre
    fine = _noise(rng, n, 1.0, 2.0, 0.3 * m)
    mid = _noise(rng, n, 1.0, 0.2 * m, 2.0 * m)
    coarse = _noise(rng, n, 1.2, 1.5 * m, n)
    tint = np.ones(3, np.float32)
    if kind == "road":
        # asphalt grain is low-contrast in real road images: keep it faint, with stronger patch-scale variation
        g = 1 + 0.07 * _photo("gravel", crop, n, texel_m, rng, 1.5) + 0.03 * fine + 0.08 * mid + 0.15 * coarse
        tint = np.array([1.0, 1.0, 0.97])
    elif kind == "sidewalk":
        g = 1 + 0.06 * _photo("gravel", crop, n, texel_m, rng, 0.8) + 0.04 * fine + 0.08 * mid + 0.12 * coarse
        _joints(g, np.arange(0, n, 1.5 * m), 1, 2, 0.55)
        _joints(g, np.arange(0, n, 1.5 * m), 0, 2, 0.55)
        tint = np.array([1.0, 0.98, 0.95])
    elif kind in ("verge", "hill", "hedge"):
        scale = {"verge": 1.0, "hill": 2.5, "hedge": 1.8}[kind]
        g = 1 + 0.25 * _photo("grass", crop, n, texel_m, rng, scale) + 0.15 * mid + 0.25 * coarse
        tint = np.array([0.8, 1.05, 0.55]) if kind != "hill" else np.array([0.9, 1.0, 0.6])
    elif kind == "roof":
        g = 1 + 0.3 * _photo("gravel", crop, n, texel_m, rng, 3.0) + 0.2 * coarse
    elif kind in ("facade_a", "facade_b"):
        if kind == "facade_a":
            g = 1 + 0.22 * _photo("brick", crop, n, texel_m, rng, 1.0) + 0.05 * mid + 0.1 * coarse
            tint = rng.uniform(0.8, 1.2, 3).astype(np.float32) * np.array([1.15, 0.9, 0.8])
        else:
            g = 1 + 0.04 * fine + 0.05 * mid + 0.1 * coarse
            _joints(g, _random_cuts(rng, n, 1.8 * m, 3.6 * m), 1, 3, 0.6)
            _joints(g, np.arange(0, n, 3.2 * m), 0, 3, 0.5)
            tint = rng.uniform(0.85, 1.15, 3).astype(np.float32)
        g = np.repeat(g[:, :, None], 3, axis=2)
        # windows: storeys every ~3.2 m from 3.5 m up, random widths/pitches, dark glass with sky reflections
        pitch = rng.uniform(3.0, 5.0) * m
        win_w = rng.uniform(0.35, 0.6) * pitch
        for storey in range(1, int(n / (3.2 * m))):
            y0 = int((storey * 3.2 + 0.9) * m)
            y1 = min(n, y0 + int(rng.uniform(1.3, 1.8) * m))
            for x0 in np.arange(rng.uniform(0, pitch), n - win_w, pitch):
                if rng.random() < 0.4:  # not every bay has a window: fewer, irregular corners
                    continue
                glass = rng.uniform(0.08, 0.6) + 0.1 * mid[y0:y1, int(x0):int(x0 + win_w)]
                g[y0:y1, int(x0):int(x0 + win_w)] = glass[..., None] * np.array([0.8, 0.9, 1.1])
                g[y0:y0 + 4, int(x0):int(x0 + win_w)] = 1.8  # lintel/frame
                g[y1 - 5:y1, int(x0):int(x0 + win_w)] = 1.6  # sill
                g[y0:y1, int(x0):int(x0) + 4] = 1.6
                g[y0:y1, int(x0 + win_w) - 4:int(x0 + win_w)] = 1.6
        # shop fronts / posters / signs at street level
        _rects(rng, g, int(n / m / 6), (0.6 * m, 2.5 * m), (0.4 * m, 1.6 * m), (0.4 * m, 2.4 * m), _poster(rng, True))
        return np.clip(g * tint / max(1e-6, float((g * tint).mean())), 0.05, 4.0).astype(np.float32)
    elif kind == "wall":
        g = 1 + 0.08 * _photo("gravel", crop, n, texel_m, rng, 4.0) + 0.05 * fine + 0.08 * mid + 0.15 * coarse
        _joints(g, _random_cuts(rng, n, 2.0 * m, 5.0 * m), 1, 3, 0.5)
        g = np.repeat(g[:, :, None], 3, axis=2)
        _rects(rng, g, int(n / m / 4), (0.5 * m, 2.0 * m), (0.3 * m, 1.2 * m), (0.3 * m, 1.8 * m), _poster(rng, True))
        return np.clip(g / g.mean(), 0.05, 4.0).astype(np.float32)
    elif kind == "tunnel_wall":
        g = 1 + 0.08 * fine + 0.1 * mid + 0.22 * coarse
        g *= 1 - 0.25 * np.clip(1 - np.arange(n)[:, None] / (1.2 * m), 0, 1)  # road grime near the kerb
        _joints(g, _random_cuts(rng, n, 2.5 * m, 5.5 * m), 1, 3, 0.4)
        g = np.repeat(g[:, :, None], 3, axis=2)
        band = slice(int(0.9 * m), int(3.6 * m))  # light tiled band, as in many road tunnels
        g[band] *= 1.35
        _joints(g, np.arange(int(0.9 * m), int(3.6 * m), 0.3 * m), 0, 1, 0.85)
        tray = slice(int(4.3 * m), int(4.6 * m))  # cable tray with brackets
        g[tray] = 0.35
        for x in np.arange(0, n, 1.5 * m):
            g[int(4.2 * m):int(4.75 * m), int(x):int(x) + 5] = 1.6
        # emergency signs (green), niche doors (orange), posters
        _rects(rng, g, int(n / m / 6), (0.5 * m, 1.0 * m), (0.25 * m, 0.5 * m), (2.3 * m, 3.0 * m),
               lambda h, w: np.ones((h, w, 3), np.float32) * np.array([0.3, 1.6, 0.6]))
        _rects(rng, g, int(n / m / 8), (0.9 * m, 1.2 * m), (1.8 * m, 2.1 * m), (0.1 * m, 0.2 * m),
               lambda h, w: np.ones((h, w, 3), np.float32) * np.array([1.8, 0.9, 0.3]))
        _rects(rng, g, int(n / m / 10), (0.4 * m, 1.5 * m), (0.3 * m, 1.0 * m), (1.0 * m, 2.5 * m), _poster(rng, True))
        return np.clip(g / g.mean(), 0.05, 4.0).astype(np.float32)
    elif kind == "tunnel_ceiling":
        g = 1 + 0.2 * _photo("gravel", crop, n, texel_m, rng, 3.0) + 0.15 * mid + 0.3 * coarse
        _joints(g, _random_cuts(rng, n, 4.0 * m, 8.0 * m), 1, 4, 0.5)
    elif kind == "pole":
        g = 1 + 0.15 * fine + 0.2 * mid + 0.3 * coarse
        _joints(g, _random_cuts(rng, n, 0.3 * m, 2.0 * m), 0, 2, 0.6)  # bands, clamps, stickers
    elif kind == "sign":
        g = np.repeat((1 + 0.05 * fine + 0.1 * coarse)[:, :, None], 3, axis=2)
        _rects(rng, g, int((n / m) ** 2 / 3.0), (0.3 * m, 1.6 * m), (0.3 * m, 1.2 * m), (0, n), _poster(rng, True))
        return np.clip(g / g.mean(), 0.05, 4.0).astype(np.float32)
    elif kind == "portal":
        g = 1 + 0.2 * _photo("gravel", crop, n, texel_m, rng, 5.0) + 0.12 * mid + 0.25 * coarse
        _joints(g, _random_cuts(rng, n, 1.5 * m, 3.5 * m), 1, 3, 0.5)
        _joints(g, np.arange(0, n, 2.0 * m), 0, 3, 0.6)
    else:
        raise ValueError(f"unknown material {kind}")
    g = np.clip(g, 0.05, None)
    g = g[:, :, None] * tint
    return (g / g.mean()).astype(np.float32)


_ATLAS_CACHE: dict = {}


def build_texture_atlas(cfg: dict):
    """Cached per texture config (cities sharing textures, e.g. train and validation, share one atlas)."""
    tex = cfg["textures"]
    key = (int(tex["seed"]), str(tex["photo_crop"]), int(tex["tile_px"]), float(tex["texel_m"]))
    if key not in _ATLAS_CACHE:
        if len(_ATLAS_CACHE) >= 3:
            _ATLAS_CACHE.clear()
        _ATLAS_CACHE[key] = _build_texture_atlas(cfg)
    return _ATLAS_CACHE[key]


def _build_texture_atlas(cfg: dict):
    """All material tiles with mip pyramids, flattened for the ray caster.

    Returns (texels uint8 flat, level_offset int64 (M, L), level_size int64 (M, L), scale float32 (M,)) where a tile
    value v in 0..255 means relative albedo v·scale/255, and level l is a (size, size, 3) block at level_offset.
    """
    tex = cfg["textures"]
    n, texel_m = int(tex["tile_px"]), float(tex["texel_m"])
    levels = int(np.log2(n)) + 1
    chunks, offsets, sizes, scales = [], np.zeros((len(MATERIALS), levels), np.int64), np.zeros(
        (len(MATERIALS), levels), np.int64), np.zeros(len(MATERIALS), np.float32)
    pos = 0
    for mi, kind in enumerate(MATERIALS):
        rng = np.random.default_rng([int(tex["seed"]), mi])
        img = make_material(kind, n, texel_m, tex["photo_crop"], rng)
        scale = float(np.percentile(img, 99.9)) * 1.02
        scales[mi] = scale
        level = img
        for li in range(levels):
            q = np.clip(np.round(level / scale * 255), 0, 255).astype(np.uint8)
            offsets[mi, li], sizes[mi, li] = pos, level.shape[0]
            chunks.append(q.ravel())
            pos += q.size
            if level.shape[0] > 1:
                s = level.shape[0] // 2
                level = level.reshape(s, 2, s, 2, 3).mean(axis=(1, 3))
    return np.concatenate(chunks), offsets, sizes, scales
