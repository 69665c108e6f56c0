"""World bounds of the scene's elements and meshes, per frame, from caches that follow the meshes'
content and matrices (the shadow regions' casters and receivers, ``shadow_region.py``)."""
from __future__ import annotations

import numpy as np

from ..scene.snapshot import box_corners, transform_points


class ElementBounds:
    """World-space (min, max) of each element of a snapshot.  Local bounds are computed once
    per mesh content (bounded cache) and moved by the world matrix every frame."""

    CACHE_LIMIT = 4096

    def __init__(self):
        self._local = {}  # geometry key -> {element: (low, high)} in local space
        self._world = {}  # (geometry key, matrix bytes) -> (elements, lows, highs) in world space

    def _local_bounds(self, mesh):
        cached = self._local.get(mesh.geometry_key)
        if cached is None:
            cached = {}
            corners = mesh.positions[mesh.triangles]  # (T, 3, 3)
            low = corners.min(axis=1)
            high = corners.max(axis=1)
            for element in np.unique(mesh.tri_element[mesh.tri_element >= 0]):
                chosen = mesh.tri_element == element
                cached[int(element)] = (low[chosen].min(axis=0).astype(np.float64),
                                        high[chosen].max(axis=0).astype(np.float64))
            if len(self._local) >= self.CACHE_LIMIT:
                self._local.pop(next(iter(self._local)))
            self._local[mesh.geometry_key] = cached
        return cached

    def _world_bounds(self, mesh):
        """(elements, lows, highs) of one mesh in world space: its local boxes' corners moved by
        its matrix, kept while its content and matrix stay (static geometry: every frame)."""
        matrix = np.asarray(mesh.matrix_world, dtype=np.float64)
        key = (mesh.geometry_key, matrix.tobytes())
        cached = self._world.get(key)
        if cached is None:
            local = self._local_bounds(mesh)
            elements = np.fromiter(local, np.int64, count=len(local))
            if len(elements):
                low = np.array([box[0] for box in local.values()])
                high = np.array([box[1] for box in local.values()])
                corners = transform_points(matrix, box_corners(low, high).reshape(-1, 3)).reshape(len(elements), 8, 3)
                cached = (elements, corners.min(axis=1), corners.max(axis=1))
                for array in cached:  # shared by every frame's bounds: read-only
                    array.setflags(write=False)
            else:
                cached = (elements, np.zeros((0, 3)), np.zeros((0, 3)))
            if len(self._world) >= self.CACHE_LIMIT:
                self._world.pop(next(iter(self._world)))
            self._world[key] = cached
        return cached

    def scene_bounds(self, snapshot):
        """World (min, max) of every mesh's triangles, of an element or not (where any receiver
        of a shadow lies), or None without triangles; per mesh kept while its content and matrix
        stay."""
        boxes = []
        for mesh in snapshot.meshes:
            if mesh.n_triangles == 0:
                continue
            matrix = np.asarray(mesh.matrix_world, dtype=np.float64)
            key = ("mesh", mesh.geometry_key, matrix.tobytes())
            cached = self._world.get(key)
            if cached is None:
                # The vertices some triangle uses (a mask: 4x faster than gathering every corner).
                used = np.zeros(len(mesh.positions), bool)
                used[np.asarray(mesh.triangles).ravel()] = True
                used = mesh.positions[used]
                corners = transform_points(matrix, box_corners(used.min(axis=0), used.max(axis=0)))
                cached = (corners.min(axis=0), corners.max(axis=0))
                if len(self._world) >= self.CACHE_LIMIT:
                    self._world.pop(next(iter(self._world)))
                self._world[key] = cached
            boxes.append(cached)
        if not boxes:
            return None
        return np.min([box[0] for box in boxes], axis=0), np.max([box[1] for box in boxes], axis=0)

    def __call__(self, snapshot) -> list:
        """Per element, (min, max) world bounds, or None when it has no triangles."""
        bounds = [None] * len(snapshot.elements)
        for mesh in snapshot.meshes:
            if mesh.n_triangles == 0:
                continue
            elements, lows, highs = self._world_bounds(mesh)
            for element, world_low, world_high in zip(elements.tolist(), lows, highs):
                if element >= len(bounds):
                    continue
                if bounds[element] is None:
                    bounds[element] = (world_low, world_high)
                else:
                    bounds[element] = (np.minimum(bounds[element][0], world_low),
                                       np.maximum(bounds[element][1], world_high))
        return bounds
