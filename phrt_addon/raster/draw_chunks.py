"""How the raster pass draws a mesh: shared vertices, spatial chunks, frustum culling.

A mesh's corners become GPU vertices once per distinct (vertex, normal, texture
coordinate), so the GPU shades a vertex once, not once per corner (about six times fewer
on a smooth mesh).  Each (material, element) group's triangles are cut into chunks of
at most ``CHUNK_TRIANGLES`` triangles that lie close together (Morton order of their
centroids); each chunk keeps its local bounding box, and a frame draws only the chunks
whose box may reach the view frustum (``boxes_outside``).  Off-screen geometry then
costs neither vertex shading nor clipping: on atrium/path1 only 32-47% of the
triangles are in view.

Plain numpy: the GPU side (``engine/gpu/resources.py``) uploads what this returns.
"""
from __future__ import annotations

import numpy as np

from ..scene.snapshot import box_corners

# Triangles per chunk: fewer chunks cost fewer draw calls, smaller ones cull tighter.  On
# llvmpipe, atrium/path1's G-buffer pass: 1024 and 4096 cull alike, 4096 draws less.
CHUNK_TRIANGLES = 4096


def shared_vertices(corners, corner_normals, uvs):
    """Corners with the same vertex, normal and texture coordinate drawn as one vertex:
    ``(vertex_of_corner (n,), first_corner (m,))``, vertices numbered in order of first
    use (indices stay local, as a vertex cache wants).  Normals and coordinates are
    compared bit for bit: corners that differ in any bit stay apart."""
    corners = np.asarray(corners).reshape(-1)
    n = len(corners)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    key = np.empty((n, 6), np.uint32)
    key[:, 0] = corners
    key[:, 1:4] = np.ascontiguousarray(corner_normals, dtype=np.float32).reshape(n, 3).view(np.uint32)
    key[:, 4:6] = np.ascontiguousarray(uvs, dtype=np.float32).reshape(n, 2).view(np.uint32)
    rows = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))).reshape(-1)
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rank[inverse.reshape(-1)], first[order]


def _spread_bits(values):
    """10-bit integers with two zero bits between their bits (Morton interleave)."""
    v = values.astype(np.uint32) & 0x3FF
    v = (v | (v << 16)) & 0x030000FF
    v = (v | (v << 8)) & 0x0300F00F
    v = (v | (v << 4)) & 0x030C30C3
    v = (v | (v << 2)) & 0x09249249
    return v


def morton_order(points) -> np.ndarray:
    """Indices that put (N, 3) points in Morton (Z-curve) order of their bounding box:
    consecutive points lie close together.  Non-finite coordinates sort as 0."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0, np.int64)
    points = np.where(np.isfinite(points), points, 0.0)
    low, high = points.min(axis=0), points.max(axis=0)
    extent = np.where(high > low, high - low, 1.0)
    cells = np.clip(((points - low) / extent * 1023.0).astype(np.int64), 0, 1023)
    code = (_spread_bits(cells[:, 0]) << 2) | (_spread_bits(cells[:, 1]) << 1) | _spread_bits(cells[:, 2])
    return np.argsort(code, kind="stable")


def chunks(positions, triangles, triangle_indices, size: int = CHUNK_TRIANGLES):
    """The triangles ``triangle_indices`` (into ``triangles``, (T, 3) indices into
    ``positions``) cut into spatially compact chunks of at most ``size``:
    ``[(triangle indices of the chunk, (2, 3) float64 local box low/high)]``."""
    triangle_indices = np.asarray(triangle_indices, dtype=np.int64)
    if len(triangle_indices) == 0:
        return []
    positions = np.asarray(positions, dtype=np.float64)
    corners = positions[np.asarray(triangles)[triangle_indices]]  # (n, 3, 3)
    ordered = triangle_indices[morton_order(corners.mean(axis=1))] if len(triangle_indices) > size \
        else triangle_indices
    result = []
    for start in range(0, len(ordered), size):
        part = ordered[start:start + size]
        points = positions[np.asarray(triangles)[part]].reshape(-1, 3)
        # A non-finite vertex makes the box infinite: such a chunk is never culled.
        with np.errstate(invalid="ignore"):
            low = np.where(np.isfinite(points), points, -np.inf).min(axis=0)
            high = np.where(np.isfinite(points), points, np.inf).max(axis=0)
        result.append((part, np.stack([low, high])))
    return result


def boxes_outside(clip_from_local, boxes) -> np.ndarray:
    """(n,) bool: which of ``boxes`` ((n, 2, 3) local low/high) lie wholly outside the
    view frustum of ``clip_from_local`` (4 x 4, OpenGL clip space: -w <= x, y, z <= w).
    A box is outside when its eight corners are all outside one frustum plane: conservative
    (a box that is outside but straddles two planes is drawn) and exact in homogeneous
    coordinates, so corners behind the camera need no special case.  A box with a
    non-finite bound is never outside."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 2, 3)
    if len(boxes) == 0:
        return np.zeros(0, bool)
    matrix = np.asarray(clip_from_local, dtype=np.float64)
    corners = box_corners(boxes[:, 0], boxes[:, 1])  # (n, 8, 3)
    finite = np.isfinite(boxes).all(axis=(1, 2))
    corners = np.where(finite[:, None, None], corners, 0.0)
    clip = corners @ matrix[:3, :3].T + matrix[:3, 3]  # x, y, z; w below
    w = corners @ matrix[3, :3] + matrix[3, 3]
    outside = np.zeros(len(boxes), bool)
    for axis in range(3):
        outside |= (clip[..., axis] < -w).all(axis=1)
        outside |= (clip[..., axis] > w).all(axis=1)
    return outside & finite
