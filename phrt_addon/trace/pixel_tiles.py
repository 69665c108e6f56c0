"""A layer's pixels grouped by screen tile, straight from the G-buffer image: the groups of
``TiledShadowRegions`` (shadow_region.py) without sorting the points.

``PointChunks`` groups points it is given: it sorts them by tile and reduces each run (5.7 ms
for arcade's opaque layer at 320x240, before a single ray).  Here the tiles are the image's own ``size`` x ``size`` blocks:
their bounds are one reshape and a few reductions over the float32 positions.  The bounds are
those of the very points ``LayerPixels.world`` gives (float32 to float64 is exact and adding
the origin rounds monotonically), so a region is the same, point for point, as over
``PointChunks``.  For a layer covering much of the image (``stage.layer_tiles``)."""
from __future__ import annotations

import numpy as np


class ImageTiles:
    """The points ``flat`` (ascending flat pixel indices into an (h, w) image) of a layer whose
    float32 positions, relative to ``origin``, are ``position`` (h, w, 3), in ``size`` x
    ``size`` screen tiles with a bounding sphere each (float64 world).  The interface of
    ``PointChunks``: ``n``, ``centre``, ``radius``, ``points_of``."""

    def __init__(self, position, flat, origin, size: int = 8):
        position = np.asarray(position)
        height, width = position.shape[:2]
        flat = np.asarray(flat, np.int64)
        self.n = len(flat)
        self.size = int(size)
        rows, cols = -(-height // self.size), -(-width // self.size)
        # The tile of each point: its index into the tiles' arrays (gathered from an image of
        # tile ids: a division per point cost 1.2 ms at 320x240).
        tile_image = (np.arange(height, dtype=np.int64) // self.size)[:, None] * cols \
            + (np.arange(width, dtype=np.int64) // self.size)[None, :]
        self.tile_of = tile_image.reshape(-1)[flat]
        # Points outside ``flat`` (not covered, or not asked for) become NaN, which fmin and fmax
        # pass over, as they pass over NaN points (no surface: in no region, as with
        # ``PointChunks``).  One copy of the image, padded to whole tiles.
        points = np.full((rows * self.size, cols * self.size, 3), np.nan, np.float32)
        wanted = np.zeros(height * width, bool)
        wanted[flat] = True
        np.copyto(points[:height, :width], position, where=wanted.reshape(height, width, 1))
        # Rows of each tile first (one fast reduction), then its columns pairwise: numpy's
        # reduction over both axes at once took 5 ms at 320x240, this 0.3.
        blocks = points.reshape(rows, self.size, cols, self.size, 3)
        low = _columns(np.fmin.reduce(blocks, axis=1), np.fmin).reshape(-1, 3).astype(np.float64)
        high = _columns(np.fmax.reduce(blocks, axis=1), np.fmax).reshape(-1, 3).astype(np.float64)
        # A tile without a point whose bounds are known (none at all, or NaN points only)
        # holds no point of any region: never tested.
        self.void = np.isnan(low).any(axis=1) | np.isnan(high).any(axis=1)
        low[self.void] = high[self.void] = 0.0
        origin = np.asarray(origin, np.float64)
        with np.errstate(invalid="ignore", over="ignore"):
            # An infinite point keeps its tile's bounds non-finite: every caster tests it.
            low, high = low + origin, high + origin
            self.centre = (low + high) / 2.0
            self.radius = 0.5 * np.sqrt(np.sum((high - low) ** 2, axis=1))

    def points_of(self, chunks: np.ndarray) -> np.ndarray:
        """Indices (ascending) of the points in the tiles ``chunks`` (a boolean mask over tiles)."""
        return np.flatnonzero((np.asarray(chunks, bool) & ~self.void)[self.tile_of])


def _columns(blocks, reduce):
    """``reduce`` (np.fmin or np.fmax) over axis 2 of (rows, cols, size, 3) tiles: halving
    pairwise while the size is even, then numpy's reduction over what is left."""
    while blocks.shape[2] > 1 and blocks.shape[2] % 2 == 0:
        blocks = reduce(blocks[:, :, 0::2], blocks[:, :, 1::2])
    return reduce.reduce(blocks, axis=2)
