"""Procedural texture images of the sample scenes as numpy arrays (no bpy).

Small (256 px) tileable images, seeded so every run gives the same pixels;
``blender_data.packed_image`` packs them into the .blend file.
"""
from __future__ import annotations

import numpy as np


def value_noise(size: int, cells: int, rng: np.random.Generator) -> np.ndarray:
    """Tileable smooth noise in [0, 1]: a random ``cells`` x ``cells`` lattice,
    bicubically eased between lattice points."""
    lattice = rng.random((cells, cells))
    coords = np.arange(size) * cells / size
    i0 = np.floor(coords).astype(int)
    t = coords - i0
    t = t * t * (3 - 2 * t)
    i1 = (i0 + 1) % cells
    rows = lattice[i0][:, i0] * (1 - t)[None, :] + lattice[i0][:, i1] * t[None, :]
    rows_next = lattice[i1][:, i0] * (1 - t)[None, :] + lattice[i1][:, i1] * t[None, :]
    return rows * (1 - t)[:, None] + rows_next * t[:, None]


def tiles(size: int, tiles_per_side: int, colour_a, colour_b, grout, rng: np.random.Generator,
          grout_px: int = 3) -> np.ndarray:
    """A checker of two stone colours with grout lines and marbling:
    ``(size, size, 3)`` sRGB in [0, 1], tileable."""
    tile = size // tiles_per_side
    y, x = np.mgrid[0:size, 0:size]
    checker = ((x // tile + y // tile) % 2).astype(np.float64)[..., None]
    base = (1 - checker) * np.asarray(colour_a) + checker * np.asarray(colour_b)
    marble = 0.6 * value_noise(size, 8, rng) + 0.4 * value_noise(size, 32, rng)
    veins = np.abs(np.sin(6.0 * marble * np.pi))
    shade = 0.82 + 0.22 * marble + 0.06 * veins
    per_tile = 0.93 + 0.14 * rng.random((tiles_per_side, tiles_per_side))
    shade = shade * per_tile[y // tile, x // tile]
    image = base * shade[..., None]
    edge = (x % tile < grout_px) | (y % tile < grout_px)
    image[edge] = np.asarray(grout)
    return np.clip(image, 0.0, 1.0)


def grass(size: int, rng: np.random.Generator) -> np.ndarray:
    """Mottled lawn green, tileable: ``(size, size, 3)`` sRGB in [0, 1]."""
    patches = 0.55 * value_noise(size, 6, rng) + 0.3 * value_noise(size, 24, rng) + 0.15 * rng.random((size, size))
    dark = np.array((0.16, 0.30, 0.08))
    light = np.array((0.36, 0.52, 0.16))
    return np.clip(dark + patches[..., None] * (light - dark), 0.0, 1.0)
