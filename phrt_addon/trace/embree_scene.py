"""Embree scenes of a replay (embreex): upload, precision clusters and ray queries.

``TraceScene`` holds the Embree scenes of one replay.  Static geometry is
uploaded once; an object whose geometry or transform changes moves to the
per-frame dynamic scenes, and the static scene is rebuilt once without it (so
an animated door does not re-upload a whole level every frame).  Geometry that
casts shadows (``rules.casts_shadow``: the same rule as the shadow maps) and
geometry that does not live in separate scenes: shadow rays only test the
casters, radiance rays test both and keep the nearest hit.

Coordinates: Embree works in float32.  Meshes are grouped into *precision
clusters* (``precision_clusters``): each cluster is uploaded relative to its own
origin, chosen so that every mesh in it is represented to a small fraction of its
own size, and rays are moved into each cluster's frame (in float64) before the
float32 conversion; distances along a ray do not change with the move.  Secondary-ray
origins are offset by an epsilon proportional to the float32 spacing at the point's
magnitude in its cluster (``ray_epsilon``), which keeps shadow acne and light leaks
away from 1e-3 to 1e5 world units.

Rays are split over a thread pool (embreex releases the GIL).
``embreex`` is imported lazily: a raster frame never imports it.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..scene import rules, shading
from ..scene.snapshot import normal_matrix, transform_points
from .triangle_table import TriangleTable, hit_surfaces

# Rays per chunk when splitting over threads; below this a single call is cheaper.
PARALLEL_CHUNK = 16384
# Relative float32 spacing multiplier for secondary-ray offsets.
EPSILON_ULPS = 64.0
FLOAT32_EPS = float(np.finfo(np.float32).eps)
# A mesh is uploaded relative to a cluster origin at most this many times its own size away
# (float32 then keeps it to ~1e-3 of its size); at most MAX_CLUSTERS clusters per scene.
PRECISION_RATIO = 1e4
MAX_CLUSTERS = 8
MISS = -1


def worker_count() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def ray_epsilon(points: np.ndarray, scene_extent, view_distance=None) -> np.ndarray:
    """Offset for secondary-ray origins: many float32 ulps of the point's magnitude,
    with a floor relative to the scene size (works from 1e-3 to 1e5 units).  ``points`` are in the frame Embree sees them in (a cluster's); ``scene_extent`` is
    that cluster's size (a number or one per point).  ``view_distance`` (optional, per
    point): how far the ray that found the point travelled, from the camera for a
    G-buffer position or from the ray origin for a hit.  Such a point carries float32
    error of that size, which in a telephoto view of a small scene is far above the
    point's own magnitude (shadow acne without it)."""
    points = np.abs(points)
    # The largest coordinate (of (n, 3) points component by component: ``shading.largest``); NaN
    # stays NaN either way.
    magnitude = shading.largest(points) if points.shape[-1] == 3 else np.max(points, axis=-1)
    if view_distance is not None:
        magnitude = np.maximum(magnitude, np.nan_to_num(np.asarray(view_distance, np.float64), posinf=0.0))
    extent = np.asarray(scene_extent, dtype=np.float64)
    return EPSILON_ULPS * FLOAT32_EPS * (magnitude + 1e-3 * extent) + 1e-7 * extent


def precision_clusters(lows, highs):
    """Group meshes (world bounds ``lows``, ``highs``: (n, 3)) so that each is within
    ``PRECISION_RATIO`` times its own size of its cluster's origin.  Smallest meshes first
    (they need the most precision); a mesh joins the first cluster whose origin is close
    enough for both it and the cluster's smallest mesh, else starts a cluster at its centre
    (past MAX_CLUSTERS it joins the nearest).  Returns (origins (k, 3), extents (k,),
    cluster of each mesh (n,))."""
    lows, highs = np.asarray(lows, np.float64).reshape(-1, 3), np.asarray(highs, np.float64).reshape(-1, 3)
    n = len(lows)
    if n == 0:
        return np.zeros((1, 3)), np.ones(1), np.zeros(0, np.int64)
    centres = (lows + highs) / 2.0
    sizes = np.max(highs - lows, axis=1)
    sizes = np.maximum(sizes, 1e-9 * np.max(np.abs(centres), axis=1) + 1e-12)
    origins, smallest, assignment = [], [], np.zeros(n, np.int64)
    for index in np.argsort(sizes, kind="stable"):
        chosen = None
        for cluster, origin in enumerate(origins):
            reach = np.max(np.abs(centres[index] - origin)) + sizes[index] / 2.0
            if reach <= PRECISION_RATIO * min(sizes[index], smallest[cluster]):
                chosen = cluster
                break
        if chosen is None:
            if len(origins) < MAX_CLUSTERS:
                origins.append(centres[index].copy())
                smallest.append(sizes[index])
                chosen = len(origins) - 1
            else:
                chosen = int(np.argmin([np.max(np.abs(centres[index] - o)) for o in origins]))
        assignment[index] = chosen
    origins = np.array(origins)
    extents = np.array([float(np.max(highs[assignment == c].max(axis=0) - lows[assignment == c].min(axis=0)))
                        for c in range(len(origins))])
    return origins, np.maximum(extents, 1e-12), assignment


@dataclass
class _Geometry:
    """Per-Embree-geometry data for shading hits (vertices in their cluster's frame)."""

    mesh_name: str
    vertices: np.ndarray  # (V,3) float32, relative to the cluster origin
    triangles: np.ndarray  # (T,3) int32
    corner_normals: np.ndarray  # (T*3,3) float32 world
    corner_uvs: np.ndarray  # (T*3,2) float32, finite (rules.texture_coordinates)
    tri_material: np.ndarray
    tri_element: np.ndarray
    _elements: list | None = None

    def elements(self) -> list:
        """The elements its triangles belong to (computed once: the static scene keeps its
        geometries for a whole replay, and a sort of every triangle each frame showed)."""
        if self._elements is None:
            self._elements = np.unique(self.tri_element).tolist()
        return self._elements


class EmbreeSet:
    """One Embree scene and the geometry table behind its geomIDs, in a cluster's frame."""

    def __init__(self, entries, casts_shadow: bool, offset, extent):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.casts_shadow = casts_shadow
        self.offset = np.asarray(offset, np.float64)  # cluster origin in the trace frame
        self.extent = float(extent)
        self.geometries = []
        self.scene = rtcore_scene.EmbreeScene()
        for geometry in entries:
            if len(geometry.triangles) == 0:
                continue
            TriangleMesh(self.scene, geometry.vertices, geometry.triangles)
            self.geometries.append(geometry)
        self.empty = not self.geometries
        self._table = None
        if not self.empty:
            # Commit now (embreex commits on the first run) so the build is timed as upload.
            self.scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))

    def table(self) -> "TriangleTable":
        """Every geometry's triangles in one table (built on the first hit shaded)."""
        if self._table is None:
            self._table = TriangleTable(self.geometries)
        return self._table

    def local(self, origins):
        """Trace-frame ray origins (float64) in this set's frame, as Embree's float32."""
        return np.ascontiguousarray(np.asarray(origins, np.float64) - self.offset, dtype=np.float32)


class TraceScene:
    """Embree scenes for a replay; call ``update(snapshot)`` once per frame."""

    def __init__(self, threads: int | None = None):
        self.threads = threads or worker_count()
        self._pool = ThreadPoolExecutor(self.threads) if self.threads > 1 else None
        self.origin = None
        self.extent = 1.0
        self._static_state = {}  # mesh name -> (geometry key, matrix bytes)
        self._dynamic_names = set()
        self._static = []
        self._dynamic = []
        self._element_set = np.full(1, -1, np.int64)  # element + 1 -> index into sets() (its cluster's frame)
        self._frames = None  # (sets, their offsets, their extents) of the last ``epsilon`` (``_set_frames``)
        self.stats = {"upload_ms": 0.0, "static_builds": 0, "static_triangles": 0, "dynamic_triangles": 0,
                      "clusters": 0, "embree_ms": 0.0}

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None
        self._static, self._dynamic = [], []
        self._frames = None

    def sets(self):
        return self._static + self._dynamic

    def _entry(self, mesh, cluster_origin):
        world = transform_points(mesh.matrix_world, mesh.positions) - cluster_origin
        normals = np.asarray(mesh.corner_normals, dtype=np.float64) @ normal_matrix(mesh.matrix_world).T
        return _Geometry(mesh.name, world.astype(np.float32), np.ascontiguousarray(mesh.triangles, dtype=np.int32),
                         shading.normalize(normals).astype(np.float32),
                         rules.texture_coordinates(mesh.corner_uvs, 3 * mesh.n_triangles),
                         mesh.tri_material, mesh.tri_element)

    def update(self, snapshot, casts_shadow=None):
        """Bring the Embree scenes in line with the snapshot; returns upload ms of this frame.
        ``casts_shadow``: per material (default: ``rules.casts_shadow`` of each)."""
        start = time.perf_counter()
        self._frames = None  # the sets are made again below: the old ones are not kept alive
        if casts_shadow is None:
            casts_shadow = np.array([rules.casts_shadow(m) for m in snapshot.materials], bool)
        casts_shadow = np.asarray(casts_shadow, bool)
        state = {m.name: (m.geometry_key, np.asarray(m.matrix_world, np.float64).tobytes())
                 for m in snapshot.meshes if m.n_triangles}
        changed = {name for name, value in state.items()
                   if name in self._static_state and self._static_state[name] != value}
        removed = set(self._static_state) - set(state)
        if self._static_state and not set(self._static_state) - changed - removed:
            # Nothing of the static scene is left (another file with the same object names, or
            # everything moved): start over, centred on the new geometry.
            self.origin = None
            self._static_state, self._dynamic_names, self._static = {}, set(), []
            changed, removed = set(), set()
        if self.origin is None:
            low, high = snapshot.bounds()
            self.origin = (low + high) / 2.0
            self.extent = max(float(np.max(high - low)), 1e-6)
        rebuild_static = not self._static and not self._static_state or bool(changed or removed)
        if changed:
            self._dynamic_names |= changed
        if rebuild_static:
            self._static_state = {name: value for name, value in state.items() if name not in self._dynamic_names}
            static_meshes = [m for m in snapshot.meshes if m.name in self._static_state]
            self._static = self._build_sets(static_meshes, casts_shadow)
            self.stats["static_builds"] += 1
            self.stats["static_triangles"] = sum(m.n_triangles for m in static_meshes)
        # New objects that appear after the static build and moving objects are dynamic.
        dynamic_meshes = [m for m in snapshot.meshes if m.n_triangles and m.name not in self._static_state]
        self._dynamic = self._build_sets(dynamic_meshes, casts_shadow) if dynamic_meshes else []
        self.stats["dynamic_triangles"] = sum(m.n_triangles for m in dynamic_meshes)
        # Element -> the set (cluster frame) its triangles are in, as an array indexed by element + 1.
        pairs = [(int(element), set_index) for set_index, embree_set in enumerate(self.sets())
                 for geometry in embree_set.geometries for element in geometry.elements()]
        lookup = np.full(max([element for element, _ in pairs] + [-1]) + 2, -1, np.int64)
        for element, set_index in reversed(pairs):  # the first set holding the element wins
            lookup[element + 1] = set_index
        self._element_set = lookup
        elapsed = (time.perf_counter() - start) * 1000.0
        self.stats["upload_ms"] = elapsed
        return elapsed

    def _build_sets(self, meshes, casts_shadow):
        meshes = [m for m in meshes if m.n_triangles]
        if not meshes:
            return []
        bounds = [(world.min(axis=0), world.max(axis=0)) for world in (m.world_positions() for m in meshes)]
        origins, extents, assignment = precision_clusters([b[0] for b in bounds], [b[1] for b in bounds])
        self.stats["clusters"] = len(origins)
        sets = []
        for cluster, cluster_origin in enumerate(origins):
            casters, others = [], []
            for mesh in (m for m, c in zip(meshes, assignment) if c == cluster):
                entry = self._entry(mesh, cluster_origin)
                caster = casts_shadow[entry.tri_material] if len(casts_shadow) else \
                    np.ones(len(entry.triangles), bool)
                for target, mask in ((casters, caster), (others, ~caster)):
                    if np.all(mask):
                        target.append(entry)
                    elif np.any(mask):
                        keep = np.flatnonzero(mask)
                        corners = (keep[:, None] * 3 + np.arange(3)).ravel()
                        target.append(_Geometry(entry.mesh_name, entry.vertices, entry.triangles[keep],
                                                entry.corner_normals[corners], entry.corner_uvs[corners],
                                                entry.tri_material[keep], entry.tri_element[keep]))
            offset = cluster_origin - self.origin
            for flag, entries in ((True, casters), (False, others)):
                if entries:
                    sets.append(EmbreeSet(entries, flag, offset, extents[cluster]))
        return sets

    def to_trace(self, world_points):
        return np.asarray(world_points, dtype=np.float64) - self.origin

    # -- ray offsets ----------------------------------------------------------
    def epsilon(self, points_trace, view_distance=None, set_index=None, element=None) -> np.ndarray:
        """``ray_epsilon`` of trace-frame points in the frame of the cluster they lie in: given
        by the set of a hit (``set_index``) or the element of a G-buffer pixel (``element``),
        else the nearest cluster origin."""
        points_trace = np.asarray(points_trace, np.float64).reshape(-1, 3)
        sets = self.sets()
        if not sets:
            return ray_epsilon(points_trace, self.extent, view_distance)
        offsets, extents = self._set_frames(sets)
        if set_index is None and element is not None:
            element = np.asarray(element, np.int64) + 1
            known = (element >= 0) & (element < len(self._element_set))
            set_index = np.where(known, self._element_set[np.where(known, element, 0)], -1)
        if set_index is None:
            set_index = np.full(len(points_trace), -1, np.int64)
        set_index = np.asarray(set_index, np.int64).copy()
        unknown = set_index < 0
        if np.any(unknown):
            distance = np.max(np.abs(points_trace[unknown][:, None, :] - offsets[None, :, :]), axis=2)
            set_index[unknown] = np.argmin(distance, axis=1)
        local = points_trace - np.take(offsets, set_index, axis=0)  # rows: faster than offsets[set_index]
        return ray_epsilon(local, extents[set_index], view_distance)

    def _set_frames(self, sets):
        """The sets' offsets (k, 3) and extents (k,) as arrays, made again when the sets change."""
        kept = self._frames  # (the sets themselves: their ids cannot be reused, offsets, extents)
        if kept is None or len(kept[0]) != len(sets) or any(a is not b for a, b in zip(kept[0], sets)):
            kept = self._frames = (tuple(sets), np.array([s.offset for s in sets]),
                                   np.array([s.extent for s in sets]))
        return kept[1], kept[2]

    # -- queries ------------------------------------------------------------
    def _run(self, scene, origins, directions, **kwargs):
        """Embree's own queries, their wall time summed in ``stats["embree_ms"]`` (item_costs.py)."""
        start = time.perf_counter()
        try:
            return self._query(scene, origins, directions, **kwargs)
        finally:
            self.stats["embree_ms"] += (time.perf_counter() - start) * 1e3

    def _query(self, scene, origins, directions, **kwargs):
        n = len(origins)
        if self._pool is None or n < 2 * PARALLEL_CHUNK:
            return scene.run(origins, directions, **kwargs)
        bounds = np.linspace(0, n, min(self.threads * 4, n // PARALLEL_CHUNK) + 1).astype(int)
        dists = kwargs.pop("dists", None)
        jobs = [self._pool.submit(scene.run, origins[a:b], directions[a:b],
                                  dists=None if dists is None else dists[a:b].copy(), **kwargs)
                for a, b in zip(bounds[:-1], bounds[1:])]
        parts = [job.result() for job in jobs]
        if isinstance(parts[0], dict):
            return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
        return np.concatenate(parts)

    def occluded(self, origins, directions, max_distance) -> np.ndarray:
        """True where a shadow caster lies within ``max_distance`` (trace-frame rays)."""
        origins = np.asarray(origins, dtype=np.float64)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        result = np.zeros(len(origins), bool)
        if len(origins) == 0:
            return result
        dists = np.minimum(np.asarray(max_distance, np.float64).reshape(-1), 1e30)  # +inf: 1e30; -inf stays
        dists[np.isnan(dists)] = 0.0
        dists = dists.astype(np.float32)
        for embree_set in self.sets():
            if not embree_set.casts_shadow or embree_set.empty:
                continue
            if not np.any(result):  # no ray blocked yet: no gather copies (most calls end here)
                hits = self._run(embree_set.scene, embree_set.local(origins), directions, dists=dists.copy(),
                                 query="OCCLUDED")
                result |= np.asarray(hits) != MISS
                continue
            todo = np.flatnonzero(~result)
            if len(todo) == 0:
                break
            hits = self._run(embree_set.scene, embree_set.local(origins[todo]), directions[todo],
                             dists=dists[todo].copy(), query="OCCLUDED")
            result[todo[np.asarray(hits) != MISS]] = True
        return result

    def intersect(self, origins, directions):
        """Nearest hit over all scenes: dict with t (inf on miss), set index, geometry, prim, u, v, Ng."""
        origins = np.asarray(origins, dtype=np.float64)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        n = len(origins)
        best = None
        sets = self.sets()
        for index, embree_set in enumerate(sets):
            if embree_set.empty or n == 0:
                continue
            out = self._run(embree_set.scene, embree_set.local(origins), directions, output=1)
            if best is None:
                # The first set's arrays are taken as they are (Embree leaves prim -1 and u, v, Ng 0
                # on a miss): a whole-array np.where per field cost ~15% of the Embree time.
                miss = out["geomID"] == MISS
                t = out["tfar"].astype(np.float64)
                t[miss] = np.inf
                best = {"t": t, "set": np.where(miss, -1, index), "geom": out["geomID"], "prim": out["primID"],
                        "u": out["u"], "v": out["v"], "Ng": out["Ng"]}
                continue
            # Later sets: scatter only the rays they hit first.
            hit = np.flatnonzero((out["geomID"] != MISS) & (out["tfar"] < best["t"]))
            best["t"][hit] = out["tfar"][hit]
            best["set"][hit] = index
            for key, field in (("geom", "geomID"), ("prim", "primID"), ("u", "u"), ("v", "v"), ("Ng", "Ng")):
                best[key][hit] = out[field][hit]
        if best is None:
            best = {"t": np.full(n, np.inf), "set": np.full(n, -1), "geom": np.full(n, -1), "prim": np.full(n, -1),
                    "u": np.zeros(n, np.float32), "v": np.zeros(n, np.float32), "Ng": np.zeros((n, 3), np.float32)}
        best["sets"] = sets
        return best

    @staticmethod
    def hit_surfaces(hits, mask):
        """Shading attributes of the hits selected by ``mask``: indices, material, element, shading
        and geometric normals (unit, outward as authored), uv and the set index of each hit."""
        return hit_surfaces(hits, mask)
