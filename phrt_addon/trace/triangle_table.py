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
    and geometric normals (unit, outward as authored), uv and the set index of each hit."""
    indices = np.flatnonzero(mask)
    material = np.zeros(len(indices), np.int64)
    element = np.full(len(indices), -1, np.int64)
    normal = np.zeros((len(indices), 3))
    uv = np.zeros((len(indices), 2))
    sets = hits["sets"]
    set_index = hits["set"][indices]
    geom_index = hits["geom"][indices]
    prim = hits["prim"][indices]
    u = hits["u"][indices].astype(np.float64)
    v = hits["v"][indices].astype(np.float64)
    barycentric = np.stack([1.0 - u - v, u, v], axis=1)
    for s in np.unique(set_index):
        chosen = np.flatnonzero(set_index == s) if len(sets) > 1 else slice(None)
        table = sets[s].table()
        rows = table.first[geom_index[chosen]] + prim[chosen]
        material[chosen] = table.material[rows]
        element[chosen] = table.element[rows]
        weights = barycentric[chosen][:, :, None]
        normal[chosen] = np.sum(weights * table.corner_normals[rows], axis=1)
        uv[chosen] = np.sum(weights * table.corner_uvs[rows], axis=1)
    geometric = shading.normalize(hits["Ng"][indices].astype(np.float64))
    normal = shading.normalize(normal)
    degenerate = np.linalg.norm(normal, axis=1) < 0.5
    normal[degenerate] = geometric[degenerate]
    # Orient the geometric normal like the authored (outward) shading normal.
    flip = np.sum(geometric * normal, axis=1) < 0
    geometric[flip] *= -1.0
    return indices, material, element, normal, geometric, uv, set_index
