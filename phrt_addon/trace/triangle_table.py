"""The triangles of an Embree set's geometries in one table, for shading hits (embree_scene.py)."""
from __future__ import annotations

import numpy as np

from ..scene import shading


class TriangleTable:
    """The triangles of a set's geometries concatenated, indexed by (geomID, primID): the hits of
    a batch are shaded with one gather per set, not a round of numpy calls per geometry hit (a
    reflection of 700 rays spent 1.3 ms in that loop on atrium).  The geometries' arrays become
    views into the table (no copy kept twice)."""

    def __init__(self, geometries):
        counts = np.array([len(g.triangles) for g in geometries], np.int64)
        self.first = np.r_[0, np.cumsum(counts)[:-1]].astype(np.int64)  # first row of each geometry
        self.material = np.concatenate([np.asarray(g.tri_material, np.int64) for g in geometries])
        self.element = np.concatenate([np.asarray(g.tri_element, np.int64) for g in geometries])
        self.corner_normals = np.concatenate([g.corner_normals for g in geometries]).reshape(-1, 3, 3)
        self.corner_uvs = np.concatenate([g.corner_uvs for g in geometries]).reshape(-1, 3, 2)
        for geometry, first, count in zip(geometries, self.first, counts):
            geometry.corner_normals = self.corner_normals[first:first + count].reshape(-1, 3)
            geometry.corner_uvs = self.corner_uvs[first:first + count].reshape(-1, 2)


def hit_surfaces(hits, mask):
    """Shading attributes of the hits selected by ``mask``: indices, material, element, shading
    and geometric normals (unit, outward as authored), uv and the set index of each hit.

    Whole-array steps only, the weighted corners summed term by term: a bounce level of a few
    dozen rays is paid in numpy calls, not in rays (0.08 ms a level before, in reductions over
    axes of 3 and per-set copies)."""
    indices = np.flatnonzero(mask)
    sets = hits["sets"]
    if len(indices) == 0:
        none = np.zeros(0, np.int64)
        return indices, none, none.copy(), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2)), none.copy()
    set_index = hits["set"][indices]
    geom_index = hits["geom"][indices]
    prim = hits["prim"][indices]
    u = hits["u"][indices].astype(np.float64)[:, None]
    v = hits["v"][indices].astype(np.float64)[:, None]
    w = 1.0 - u - v
    used = np.flatnonzero(np.bincount(set_index, minlength=1)) if len(sets) > 1 else (0,)
    if len(used) == 1:
        table = sets[used[0]].table()
        rows = table.first[geom_index] + prim
        material, element = table.material[rows], table.element[rows]
        corner_normals, corner_uvs = table.corner_normals[rows], table.corner_uvs[rows]
    else:
        material = np.zeros(len(indices), np.int64)
        element = np.full(len(indices), -1, np.int64)
        corner_normals = np.zeros((len(indices), 3, 3), np.float32)
        corner_uvs = np.zeros((len(indices), 3, 2), np.float32)
        for s in used:
            chosen = np.flatnonzero(set_index == s)
            table = sets[s].table()
            rows = table.first[geom_index[chosen]] + prim[chosen]
            material[chosen] = table.material[rows]
            element[chosen] = table.element[rows]
            corner_normals[chosen] = table.corner_normals[rows]
            corner_uvs[chosen] = table.corner_uvs[rows]
    normal = shading.normalize(w * corner_normals[:, 0] + u * corner_normals[:, 1] + v * corner_normals[:, 2])
    uv = w * corner_uvs[:, 0] + u * corner_uvs[:, 1] + v * corner_uvs[:, 2]
    geometric = shading.normalize(hits["Ng"][indices].astype(np.float64))
    degenerate = shading.dot(normal, normal) < 0.25  # a zero normal stays zero when normalised
    normal[degenerate] = geometric[degenerate]
    # Orient the geometric normal like the authored (outward) shading normal.
    geometric[shading.dot(geometric, normal) < 0] *= -1.0
    return indices, material, element, normal, geometric, uv, set_index
