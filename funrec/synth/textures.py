"""Procedural, seamlessly tiling RGB textures (wood, planks, tiles, plaster, wallpaper,
speckled stone, brushed metal) made with numpy and OpenCV.

Every texture carries detail at several scales so that feature trackers find corners on
every surface of a synthetic room.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np
import numpy.typing as npt

from funrec.typed import FloatArray, UInt8Array

TEXTURE_KINDS = ("wood", "planks", "tiles", "plaster", "wallpaper", "speckle", "brushed")
"""Names accepted by :func:`make_texture`."""


def periodic_noise(
    rng: np.random.Generator, size: int, cells: tuple[int, int] = (4, 4), octaves: int = 5, persistence: float = 0.55
) -> FloatArray:
    """Seamless fractal value noise.

    Args:
        rng: random generator.
        size: image side S in pixels (a power of two).
        cells: coarsest grid (rows, columns), powers of two; unequal values stretch the noise.
        octaves: number of octaves, each with twice the cells of the previous one.
        persistence: amplitude ratio between successive octaves.

    Returns:
        (S, S) float64 noise with zero mean and unit standard deviation that tiles seamlessly.
    """
    total = np.zeros((size, size))
    amplitude = 1.0
    for octave in range(octaves):
        rows, cols = cells[0] << octave, cells[1] << octave
        if rows > size // 2 or cols > size // 2:
            break
        grid = np.pad(rng.standard_normal((rows, cols)), 2, mode="wrap").astype(np.float32)
        sy, sx = size // rows, size // cols
        # Cubic upsampling of a wrap-padded grid, cropped to one period, tiles exactly.
        up = cv2.resize(grid, ((cols + 4) * sx, (rows + 4) * sy), interpolation=cv2.INTER_CUBIC)
        total += amplitude * up[2 * sy : 2 * sy + size, 2 * sx : 2 * sx + size]
        amplitude *= persistence
    total -= total.mean()
    return total / max(float(total.std()), 1e-9)


def _wrap_blur(image: FloatArray, sigma: float) -> FloatArray:
    """Gaussian blur with periodic borders."""
    pad = int(np.ceil(3 * sigma)) + 1
    padded = np.pad(image, ((pad, pad), (pad, pad)) + ((0, 0),) * (image.ndim - 2), mode="wrap")
    blurred = cv2.GaussianBlur(padded.astype(np.float32), (0, 0), sigma)
    return blurred[pad:-pad, pad:-pad].astype(np.float64)


def _dots(
    rng: np.random.Generator, size: int, count: int, radius: tuple[float, float], colors: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Random filled discs on a periodic canvas.

    Returns:
        coverage: (S, S) float in [0, 1], anti-aliased disc coverage.
        paint: (S, S, 3) colour of the top-most disc at each pixel (only meaningful where covered).
    """
    scale = 4  # draw at 4x and area-average: anti-aliased discs without per-pixel loops
    canvas = np.zeros((size * scale, size * scale, 4), np.uint8)
    centres = rng.uniform(0, size, (count, 2))
    radii = rng.uniform(radius[0], radius[1], count)
    picks = rng.integers(0, len(colors), count)
    palette = np.clip(np.round(np.asarray(colors) * 255), 0, 255).astype(int)
    offsets = np.array([(dx, dy) for dx in (-size, 0, size) for dy in (-size, 0, size)], dtype=np.float64)
    for (x, y), r, k in zip(centres, radii, picks):
        color = (int(palette[k][0]), int(palette[k][1]), int(palette[k][2]), 255)
        copies = offsets + (x, y)  # wrapped copies that touch the canvas keep the texture periodic
        copies = copies[np.all((copies > -r - 1) & (copies < size + r + 1), axis=1)]
        for cx, cy in copies:
            centre = (int(round(cx * scale)), int(round(cy * scale)))
            cv2.circle(canvas, centre, max(1, int(round(r * scale))), color, -1, lineType=cv2.LINE_8)
    small = cv2.resize(canvas.astype(np.float32) / 255.0, (size, size), interpolation=cv2.INTER_AREA)
    coverage = small[..., 3].astype(np.float64)
    paint = small[..., :3].astype(np.float64) / np.maximum(coverage, 1e-6)[..., None]
    return coverage, paint


def _to_uint8(rgb: npt.ArrayLike) -> UInt8Array:
    return np.clip(np.round(np.asarray(rgb) * 255.0), 0, 255).astype(np.uint8)


def wood(rng: np.random.Generator, size: int, color: npt.ArrayLike) -> UInt8Array:
    """Wood grain running along the image rows (v), rings across the columns (u)."""
    base = np.asarray(color, dtype=np.float64)
    u = np.arange(size)[None, :] / size
    warp = periodic_noise(rng, size, (1, 2), octaves=3)
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (int(rng.integers(5, 11)) * u + 0.35 * warp))
    fibres = periodic_noise(rng, size, (4, 64), octaves=3, persistence=0.6)
    fine = periodic_noise(rng, size, (16, 16), octaves=3)
    lum = 1.0 - 0.28 * rings**3 + 0.07 * fibres + 0.05 * fine
    coverage, _ = _dots(rng, size, int(rng.integers(1, 4)), (size / 60, size / 30), np.zeros((1, 3)))
    lum *= 1.0 - 0.35 * _wrap_blur(coverage, size / 150)
    tint = base[None, None, :] * lum[..., None]
    tint[..., 0] *= 1.0 + 0.05 * rings
    return _to_uint8(tint)


def planks(rng: np.random.Generator, size: int, color: npt.ArrayLike) -> UInt8Array:
    """Floor boards: columns of wood planks with staggered end joints and dark seams."""
    grain = wood(rng, size, color).astype(np.float64) / 255.0
    count = int(rng.choice([4, 8]))
    width = size // count
    out = np.empty_like(grain)
    seam = max(1, size // 256)
    for k in range(count):
        cols = slice(k * width, (k + 1) * width)
        strip = np.roll(grain[:, cols], int(rng.integers(0, size)), axis=0) * rng.uniform(0.85, 1.12)
        joint = int(rng.integers(0, size))
        strip[np.arange(joint, joint + seam) % size] *= 0.45
        strip[:, :seam] *= 0.45
        out[:, cols] = strip
    return _to_uint8(out)


def tiles(rng: np.random.Generator, size: int, color: npt.ArrayLike) -> UInt8Array:
    """Square ceramic tiles with per-tile shade, mottling and grout lines."""
    base = np.asarray(color, dtype=np.float64)
    count = int(rng.choice([2, 4, 8]))
    pitch = size // count
    index = np.arange(size) // pitch
    shade = rng.uniform(0.85, 1.15, (count, count))[index[:, None], index[None, :]]
    mottle = periodic_noise(rng, size, (8, 8), octaves=4)
    rgb = base[None, None, :] * (shade * (1.0 + 0.09 * mottle))[..., None]
    coverage, paint = _dots(rng, size, size // 3, (0.6, 2.0), np.array([[0.2, 0.2, 0.2], [0.95, 0.95, 0.9]]))
    rgb = rgb * (1 - 0.6 * coverage[..., None]) + 0.6 * coverage[..., None] * paint
    within = np.arange(size) % pitch
    grout_width = max(2, pitch // 24)
    grout = (within[:, None] < grout_width) | (within[None, :] < grout_width)
    grout_color = np.array([0.3, 0.3, 0.3]) if base.mean() > 0.5 else np.array([0.85, 0.85, 0.8])
    rgb[grout] = grout_color
    return _to_uint8(rgb)


def plaster(rng: np.random.Generator, size: int, color: npt.ArrayLike) -> UInt8Array:
    """Painted plaster with blotches and fine speckles."""
    base = np.asarray(color, dtype=np.float64)
    blotch = periodic_noise(rng, size, (2, 2), octaves=7, persistence=0.65)
    lum = 1.0 + 0.11 * blotch
    coverage, paint = _dots(
        rng, size, size * size // 400, (0.5, 1.8), np.array([[0.35, 0.33, 0.3], [1.0, 1.0, 1.0], [0.6, 0.5, 0.4]])
    )
    rgb = base[None, None, :] * lum[..., None]
    return _to_uint8(rgb * (1 - 0.7 * coverage[..., None]) + 0.7 * coverage[..., None] * paint * base.mean() * 1.2)


def wallpaper(rng: np.random.Generator, size: int, color: npt.ArrayLike) -> UInt8Array:
    """Plaster with a jittered lattice of small motifs in an accent colour."""
    rgb = plaster(rng, size, color).astype(np.float64) / 255.0
    accent = np.clip(np.asarray(color, dtype=np.float64)[::-1] * rng.uniform(0.4, 0.8), 0, 1)
    lattice = int(rng.choice([8, 16]))
    canvas = np.zeros((3 * size, 3 * size), np.uint8)
    pitch = size / lattice
    for i in range(lattice):
        for j in range(lattice):
            x = (j + 0.5) * pitch + rng.normal(0, pitch * 0.12)
            y = (i + 0.5) * pitch + rng.normal(0, pitch * 0.12)
            r = pitch * rng.uniform(0.12, 0.3)
            corners = np.array([[0, -r], [r * 0.7, 0], [0, r], [-r * 0.7, 0]])
            for dx in (0, size, 2 * size):
                for dy in (0, size, 2 * size):
                    polygon = np.round(corners + [x + dx, y + dy]).astype(np.int32)
                    cv2.fillPoly(canvas, [polygon], 255, lineType=cv2.LINE_AA)
    motif = canvas[size : 2 * size, size : 2 * size].astype(np.float64)[..., None] / 255.0
    return _to_uint8(rgb * (1 - motif) + motif * accent)


def speckle(rng: np.random.Generator, size: int, color: npt.ArrayLike) -> UInt8Array:
    """Granite or terrazzo: a mottled base covered in small multi-coloured grains."""
    base = np.asarray(color, dtype=np.float64)
    rgb = base[None, None, :] * (1.0 + 0.08 * periodic_noise(rng, size, (4, 4)))[..., None]
    colors = np.clip(base[None, :] * rng.uniform(0.3, 1.6, (4, 1)) + rng.normal(0, 0.06, (4, 3)), 0, 1)
    coverage, paint = _dots(rng, size, size * size // 60, (0.7, 3.0), colors)
    return _to_uint8(rgb * (1 - coverage[..., None]) + coverage[..., None] * paint)


def brushed(rng: np.random.Generator, size: int, color: npt.ArrayLike) -> UInt8Array:
    """Brushed metal or appliance enamel: fine streaks along the rows, smudges and specks."""
    base = np.asarray(color, dtype=np.float64)
    streaks = periodic_noise(rng, size, (64, 2), octaves=3)
    smudge = periodic_noise(rng, size, (2, 2), octaves=5, persistence=0.6)
    lum = 1.0 + 0.06 * streaks + 0.07 * smudge
    coverage, _ = _dots(rng, size, size * size // 900, (0.5, 1.5), np.zeros((1, 3)))
    return _to_uint8(base[None, None, :] * (lum * (1.0 - 0.45 * coverage))[..., None])


_MAKERS: dict[str, Callable[[np.random.Generator, int, npt.ArrayLike], UInt8Array]] = {
    "wood": wood,
    "planks": planks,
    "tiles": tiles,
    "plaster": plaster,
    "wallpaper": wallpaper,
    "speckle": speckle,
    "brushed": brushed,
}


def make_texture(kind: str, rng: np.random.Generator, size: int, color: npt.ArrayLike) -> UInt8Array:
    """Make one texture.

    Args:
        kind: one of :data:`TEXTURE_KINDS`.
        rng: random generator (the only source of randomness).
        size: side S in pixels, a power of two >= 32.
        color: (3,) base RGB in [0, 1].

    Returns:
        (S, S, 3) uint8 RGB image that tiles seamlessly.
    """
    if kind not in _MAKERS:
        raise ValueError(f"unknown texture kind {kind!r}; expected one of {TEXTURE_KINDS}")
    if size < 32 or size & (size - 1):
        raise ValueError(f"texture size must be a power of two >= 32, got {size}")
    return _MAKERS[kind](rng, size, color)


__all__ = ["TEXTURE_KINDS", "make_texture", "periodic_noise"]
