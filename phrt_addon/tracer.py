"""Ray tracing stage on Embree (embreex): shadows, reflections and refractions.

``TraceScene`` holds the Embree scenes of one replay.  Static geometry is
uploaded once; an object whose geometry or transform changes moves to the
per-frame dynamic scenes, and the static scene is rebuilt once without it (so
an animated door does not re-upload a whole level every frame).  Opaque and
transparent geometry live in separate scenes: shadow rays only test the opaque
ones (glass and water do not cast shadows, matching the raster shadow maps),
radiance rays test both and keep the nearest hit.

Coordinates: Embree works in float32, so every scene is built relative to a
``trace origin`` (the scene centre when the static scene was built) and ray
origins are offset along the surface normal by an epsilon proportional to the
float32 spacing at the point's magnitude (``ray_epsilon``), which keeps shadow
acne and light leaks away from 1e-3 to 1e5 world units.

Rays are split over a thread pool (embreex releases the GIL).
``embreex`` is imported lazily: a raster frame never imports it.
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from . import shading
from .scene import normal_matrix, transform_points

# Rays per chunk when splitting over threads; below this a single call is cheaper.
PARALLEL_CHUNK = 16384
# Relative float32 spacing multiplier for secondary-ray offsets.
EPSILON_ULPS = 64.0
FLOAT32_EPS = float(np.finfo(np.float32).eps)
# Reflections are traced on surfaces up to this roughness (a single mirror-direction
# ray, blended towards the environment as roughness grows; see ``reflection_blend``).
ROUGHNESS_LIMIT = 0.5
# A total internal reflection costs this fraction of a bounce: it does not branch, and light that
# enters a glass block through a side face needs a few of them to get out.
TIR_BOUNCE_COST = 0.25
MISS = -1


def worker_count() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def ray_epsilon(points: np.ndarray, scene_extent: float, view_distance=None) -> np.ndarray:
    """Offset for secondary-ray origins: many float32 ulps of the point's magnitude,
    with a floor relative to the scene size (works from 1e-3 to 1e5 units).

    ``view_distance`` (optional, per point): how far the ray that found the point travelled,
    from the camera for a G-buffer position or from the ray origin for a hit.  Such a point
    carries float32 error of that size, which in a telephoto view of a small scene is far above
    the point's own magnitude (shadow acne without it)."""
    magnitude = np.max(np.abs(points), axis=-1)
    if view_distance is not None:
        magnitude = np.maximum(magnitude, np.nan_to_num(np.asarray(view_distance, np.float64), posinf=0.0))
    return EPSILON_ULPS * FLOAT32_EPS * (magnitude + 1e-3 * scene_extent) + 1e-7 * scene_extent


def reflection_blend(roughness):
    """Weight of the traced mirror reflection vs the environment term: 1 for a mirror,
    falling to 0 at ``ROUGHNESS_LIMIT``."""
    return np.clip(1.0 - np.asarray(roughness) / ROUGHNESS_LIMIT, 0.0, 1.0) ** 2


@dataclass
class _Geometry:
    """Per-Embree-geometry data for shading hits (trace-frame coordinates)."""

    mesh_name: str
    vertices: np.ndarray  # (V,3) float32
    triangles: np.ndarray  # (T,3) int32
    corner_normals: np.ndarray  # (T*3,3) float32 world
    corner_uvs: np.ndarray | None
    tri_material: np.ndarray
    tri_element: np.ndarray


class _EmbreeSet:
    """One Embree scene and the geometry table behind its geomIDs."""

    def __init__(self, entries):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.geometries = []
        self.scene = rtcore_scene.EmbreeScene()
        for geometry in entries:
            if len(geometry.triangles) == 0:
                continue
            TriangleMesh(self.scene, geometry.vertices, geometry.triangles)
            self.geometries.append(geometry)
        self.empty = not self.geometries
        if not self.empty:
            # Commit now (embreex commits on the first run) so the build is timed as upload.
            self.scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, 1]], np.float32))


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
        self.stats = {"upload_ms": 0.0, "static_builds": 0, "static_triangles": 0, "dynamic_triangles": 0}

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(wait=False)
            self._pool = None

    # -- geometry -----------------------------------------------------------
    def _entry(self, mesh):
        world = transform_points(mesh.matrix_world, mesh.positions) - self.origin
        normals = np.asarray(mesh.corner_normals, dtype=np.float64) @ normal_matrix(mesh.matrix_world).T
        return _Geometry(mesh.name, world.astype(np.float32), np.ascontiguousarray(mesh.triangles, dtype=np.int32),
                         shading.normalize(normals).astype(np.float32), mesh.corner_uvs,
                         mesh.tri_material, mesh.tri_element)

    def update(self, snapshot, transparent_materials: np.ndarray):
        """Bring the Embree scenes in line with the snapshot; returns upload ms of this frame."""
        start = time.perf_counter()
        state = {m.name: (m.geometry_key, np.asarray(m.matrix_world, np.float64).tobytes())
                 for m in snapshot.meshes if m.n_triangles}
        changed = {name for name, value in state.items()
                   if name in self._static_state and self._static_state[name] != value}
        removed = set(self._static_state) - set(state)
        if self._static_state and not set(self._static_state) - changed - removed:
            # Nothing of the static scene is left (another file with the same object names, or
            # everything moved): start over, centred on the new geometry, so that a scene far from
            # the old origin keeps its float32 precision and a fitting ray epsilon.
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
            self._static = self._build_sets(static_meshes, transparent_materials)
            self.stats["static_builds"] += 1
            self.stats["static_triangles"] = sum(m.n_triangles for m in static_meshes)
        # New objects that appear after the static build and moving objects are dynamic.
        dynamic_meshes = [m for m in snapshot.meshes if m.n_triangles and m.name not in self._static_state]
        self._dynamic = self._build_sets(dynamic_meshes, transparent_materials) if dynamic_meshes else []
        self.stats["dynamic_triangles"] = sum(m.n_triangles for m in dynamic_meshes)
        elapsed = (time.perf_counter() - start) * 1000.0
        self.stats["upload_ms"] = elapsed
        return elapsed

    def _build_sets(self, meshes, transparent_materials):
        opaque, transparent = [], []
        for mesh in meshes:
            entry = self._entry(mesh)
            is_transparent = transparent_materials[entry.tri_material] if len(transparent_materials) else \
                np.zeros(len(entry.triangles), bool)
            for target, mask in ((opaque, ~is_transparent), (transparent, is_transparent)):
                if np.all(mask):
                    target.append(entry)
                elif np.any(mask):
                    keep = np.flatnonzero(mask)
                    corners = (keep[:, None] * 3 + np.arange(3)).ravel()
                    target.append(_Geometry(entry.mesh_name, entry.vertices, entry.triangles[keep],
                                            entry.corner_normals[corners],
                                            None if entry.corner_uvs is None else entry.corner_uvs[corners],
                                            entry.tri_material[keep], entry.tri_element[keep]))
        return [("opaque", _EmbreeSet(opaque)), ("transparent", _EmbreeSet(transparent))]

    def to_trace(self, world_points):
        return np.asarray(world_points, dtype=np.float64) - self.origin

    # -- queries ------------------------------------------------------------
    def _run(self, scene, origins, directions, **kwargs):
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
        """True where an opaque surface lies within ``max_distance`` (trace-frame rays)."""
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        result = np.zeros(len(origins), bool)
        if len(origins) == 0:
            return result
        dists = np.minimum(np.nan_to_num(max_distance, nan=0.0, posinf=1e30), 1e30).astype(np.float32)
        for kind, embree_set in self._static + self._dynamic:
            if kind != "opaque" or embree_set.empty:
                continue
            if not np.any(result):  # no ray blocked yet: no gather copies (most calls end here)
                hits = self._run(embree_set.scene, origins, directions, dists=dists.copy(), query="OCCLUDED")
                result |= np.asarray(hits) != MISS
                continue
            todo = np.flatnonzero(~result)
            if len(todo) == 0:
                break
            hits = self._run(embree_set.scene, origins[todo], directions[todo], dists=dists[todo].copy(),
                             query="OCCLUDED")
            result[todo[np.asarray(hits) != MISS]] = True
        return result

    def intersect(self, origins, directions):
        """Nearest hit over all scenes: dict with t (inf on miss), set index, geometry, prim, u, v, Ng."""
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        n = len(origins)
        best = None
        sets = self._static + self._dynamic
        for index, (_, embree_set) in enumerate(sets):
            if embree_set.empty or n == 0:
                continue
            out = self._run(embree_set.scene, origins, directions, output=1)
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

    def hit_surfaces(self, hits, mask):
        """Shading attributes of the hits selected by ``mask``: material, element, shading and
        geometric normals (unit, outward as authored), uv."""
        indices = np.flatnonzero(mask)
        material = np.zeros(len(indices), np.int64)
        element = np.full(len(indices), -1, np.int64)
        normal = np.zeros((len(indices), 3))
        uv = np.zeros((len(indices), 2))
        has_uv = np.zeros(len(indices), bool)
        sets = hits["sets"]
        set_index = hits["set"][indices]
        geom_index = hits["geom"][indices]
        prim = hits["prim"][indices]
        u = hits["u"][indices].astype(np.float64)
        v = hits["v"][indices].astype(np.float64)
        barycentric = np.stack([1.0 - u - v, u, v], axis=1)
        for s in np.unique(set_index):
            embree_set = sets[s][1]
            in_set = set_index == s
            for g in np.unique(geom_index[in_set]):
                chosen = np.flatnonzero(in_set & (geom_index == g))
                geometry = embree_set.geometries[g]
                triangles = prim[chosen]
                material[chosen] = geometry.tri_material[triangles]
                element[chosen] = geometry.tri_element[triangles]
                corners = triangles[:, None] * 3 + np.arange(3)
                normal[chosen] = np.einsum("nk,nkc->nc", barycentric[chosen], geometry.corner_normals[corners])
                if geometry.corner_uvs is not None:
                    uv[chosen] = np.einsum("nk,nkc->nc", barycentric[chosen], geometry.corner_uvs[corners])
                    has_uv[chosen] = True
        geometric = shading.normalize(hits["Ng"][indices].astype(np.float64))
        normal = shading.normalize(normal)
        degenerate = np.linalg.norm(normal, axis=1) < 0.5
        normal[degenerate] = geometric[degenerate]
        # Orient the geometric normal like the authored (outward) shading normal.
        flip = np.sum(geometric * normal, axis=1) < 0
        geometric[flip] *= -1.0
        return indices, material, element, normal, geometric, uv, has_uv


class RadianceTracer:
    """Shades ray hits with the shared BRDF, shadow rays and recursion to ``max_bounces``."""

    def __init__(self, trace_scene: TraceScene, snapshot, materials: shading.MaterialTable, textures=None):
        self.scene = trace_scene
        self.snapshot = snapshot
        self.materials = materials
        self.textures = textures or {}
        self.world = np.asarray(snapshot.world_color, dtype=np.float64)
        self.max_bounces = int(snapshot.settings.max_bounces)
        self.rays = 0
        self.shadow_rays = 0

    def _albedo(self, material, uv, has_uv):
        albedo = self.materials.base_color[material].copy()
        for index in np.unique(material):
            texture = self.textures.get(int(index))
            if texture is None:
                continue
            chosen = (material == index) & has_uv
            if np.any(chosen):
                albedo[chosen] *= sample_texture(texture, uv[chosen])[:, :3]
        return albedo

    def direct(self, points_trace, surface: shading.SurfaceSamples, view_distance=None):
        """Direct light with traced shadows at trace-frame points (``view_distance``: see ray_epsilon)."""
        total = np.zeros((len(points_trace), 3))
        if len(points_trace) == 0:
            return total
        origin_world = self.scene.origin
        eps = ray_epsilon(points_trace, self.scene.extent, view_distance)
        for light in self.snapshot.lights:
            direction, distance, irradiance = shading.light_incidence(light, points_trace, origin_world)
            contribution = shading.brdf_cosine(surface, direction) * irradiance
            lit = np.any(contribution > 0, axis=1)
            if light.cast_shadows and np.any(lit):
                idx = np.flatnonzero(lit)
                start = points_trace[idx] + surface.normal[idx] * eps[idx, None]
                blocked = self.scene.occluded(start, direction[idx], distance[idx] - 2 * eps[idx])
                self.shadow_rays += len(idx)
                contribution[idx[blocked]] = 0.0
            total += contribution
        return total

    def radiance(self, origins, directions, depth):
        """Radiance arriving along trace-frame rays (N,3); ``depth``: the bounces so far,
        a number or one per ray."""
        n = len(origins)
        depth = np.broadcast_to(np.asarray(depth, dtype=np.float64), (n,))
        result = np.broadcast_to(self.world, (n, 3)).copy()
        if n == 0:
            return result
        self.rays += n
        hits = self.scene.intersect(origins, directions)
        hit_mask = np.isfinite(hits["t"]) & (hits["geom"] >= 0)
        if not np.any(hit_mask):
            return result
        idx, material, _, normal, geometric, uv, has_uv = self.scene.hit_surfaces(hits, hit_mask)
        dirs = directions[idx].astype(np.float64)
        points = origins[idx].astype(np.float64) + dirs * hits["t"][idx][:, None]
        # Which side: the ray arrives from outside where it opposes the outward normal.
        entering = np.sum(geometric * dirs, axis=1) < 0
        facing = np.where(entering[:, None], normal, -normal)
        geometric_facing = np.where(entering[:, None], geometric, -geometric)
        m = self.materials
        surface = shading.SurfaceSamples(
            position=points, normal=facing, view=-dirs, albedo=self._albedo(material, uv, has_uv),
            metallic=m.metallic[material], roughness=m.roughness[material],
            transmission=m.transmission[material], ior=m.ior[material], emission=m.emission[material])
        travelled = hits["t"][idx]
        color = surface.emission + self.direct(points, surface, travelled)
        diffuse_ambient, env_fresnel = shading.ambient(surface, self.world)
        color += diffuse_ambient
        transmissive = surface.transmission * (1.0 - surface.metallic)
        eps = ray_epsilon(points, self.scene.extent, travelled)
        # Dielectric Fresnel for the transmissive part (exact, with total internal reflection).
        eta = np.where(entering, 1.0 / surface.ior, surface.ior)
        cos_i = np.clip(np.sum(-dirs * facing, axis=1), 0.0, 1.0)
        fresnel_t = shading.fresnel_dielectric(cos_i, 1.0 / eta)
        reflect_weight = env_fresnel * (1.0 - transmissive)[:, None] + (transmissive * fresnel_t)[:, None]
        blend = reflection_blend(surface.roughness)
        depth = depth[idx]
        can_bounce = depth < self.max_bounces
        transmits = transmissive > 1e-3
        # Total internal reflection: nothing is refracted, and the bounce costs only
        # TIR_BOUNCE_COST, so light entering a glass side face can get out again.
        total_internal = transmits & (fresnel_t >= 1.0)
        next_depth = depth + np.where(total_internal, TIR_BOUNCE_COST, 1.0)
        reflected = np.broadcast_to(self.world, (len(idx), 3)).copy()
        trace_reflection = can_bounce & (blend > 0) & (reflect_weight.max(axis=1) > 0.02)
        if np.any(trace_reflection):
            r = np.flatnonzero(trace_reflection)
            direction = shading.reflect(dirs[r], facing[r])
            start = points[r] + geometric_facing[r] * eps[r, None]
            traced = self.radiance(start, direction, next_depth[r])
            reflected[r] = blend[r, None] * traced + (1.0 - blend[r, None]) * self.world
        color += reflect_weight * reflected
        refracts = transmits & ~total_internal
        trace_refraction = can_bounce & refracts
        if np.any(trace_refraction):
            t = np.flatnonzero(trace_refraction)
            direction, _ = shading.refract(dirs[t], facing[t], eta[t])
            start = points[t] - geometric_facing[t] * eps[t, None]
            through = self.radiance(start, direction, next_depth[t])
            tint = np.where(entering[t, None], surface.albedo[t], 1.0)
            weight = (transmissive[t] * (1.0 - fresnel_t[t]))[:, None] * tint
            color[t] += weight * through
        out_of_bounces = refracts & ~can_bounce
        if np.any(out_of_bounces):
            # Out of bounces inside glass: the environment is the best guess.
            o = np.flatnonzero(out_of_bounces)
            color[o] += (transmissive[o] * (1.0 - fresnel_t[o]))[:, None] * self.world
        result[idx] = shading.finite(color)
        return result


def sample_texture(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Nearest-texel lookup with wrap-around; texture rows start at the bottom (v = 0)."""
    height, width = texture.shape[:2]
    x = np.mod(np.floor(uv[:, 0] * width), width).astype(np.int64)
    y = np.mod(np.floor(uv[:, 1] * height), height).astype(np.int64)
    return texture[y, x]
