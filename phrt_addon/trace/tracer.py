"""Ray traced radiance (the tracer's shading): shadows, reflections and refractions of hits.

``RadianceTracer`` shades the hits of rays cast in a ``trace_scene.TraceScene`` with the
BRDF of ``shading.py`` (the one the GLSL lighting implements too), shadow rays and
recursion.

Bounces (``Settings.max_bounces``): a bounce is a reflection or refraction ray,
which changes the ray's direction.  Rays from the G-buffer are bounce 1 (with
``max_bounces`` 0 nothing is reflected or refracted by the tracer); a hit of bounce
k may bounce again while k < max_bounces.  Out of bounces, a reflection sees the
environment (the raster's stand-in) and light through a transmissive surface goes
straight on, unbent (the raster's blended transparency).  A total internal
reflection costs ``TIR_BOUNCE_COST`` of a bounce.  Light passing straight through
a surface (its 1 - alpha part, or a transmissive one out of bounces) is not a
bounce; at most ``MAX_PASS_THROUGH`` surfaces are passed through per path.
Secondary rays leave along the *geometric* normal, on the side they leave
(``leave_surface``): the interpolated normal of a coarse smooth mesh can point
below the surface.
"""
from __future__ import annotations

import numpy as np

from ..scene import rules, shading
from .embree_scene import TraceScene

# Reflections are traced on surfaces up to this roughness (a single mirror-direction
# ray, blended towards the environment as roughness grows; see ``reflection_blend``).
ROUGHNESS_LIMIT = 0.5
# A total internal reflection costs this fraction of a bounce: it does not branch, and light that
# enters a glass block through a side face needs a few of them to get out.
TIR_BOUNCE_COST = 0.25
# Surfaces a path may pass straight through (alpha cards, glass out of bounces).
MAX_PASS_THROUGH = 16
# A secondary ray is traced only while its path's throughput to the camera (the product of the
# weights its bounces were taken with, largest channel) is at least this; a fainter path is given
# the world colour instead, as an untraced reflection is.  Each cut path changes its pixel by
# under PATH_CUTOFF x the radiance it would have brought back; a pixel's change is the sum over
# its cut paths (a stack of glass plates at max_bounces 8 cuts several: 4-5x in review), in
# linear values (near black a linear 4e-3 is several sRGB steps).
PATH_CUTOFF = 2e-3
# Secondary directions are kept at least this cosine away from the geometric surface.
MIN_LEAVING_COSINE = 1e-4


def reflection_blend(roughness):
    """Weight of the traced mirror reflection vs the environment term: 1 for a mirror,
    falling to 0 at ``ROUGHNESS_LIMIT``."""
    return shading.unit_clip(1.0 - np.asarray(roughness) / ROUGHNESS_LIMIT) ** 2


def leave_surface(directions, geometric_normal, side=1.0):
    """``directions`` bent just enough to leave the geometric surface on ``side`` (+1: the side
    ``geometric_normal`` points to, -1: the other).  A mirror direction about an interpolated
    normal can point into the surface on coarse smooth meshes; Embree would then hit the
    surface itself."""
    normal = geometric_normal * side
    along = shading.dot(directions, normal)
    wrong = along < MIN_LEAVING_COSINE
    if not np.any(wrong):
        return directions
    fixed = directions.copy()
    fixed[wrong] += (MIN_LEAVING_COSINE - along[wrong])[:, None] * normal[wrong]
    fixed[wrong] = shading.normalize(fixed[wrong])
    return fixed


class RadianceTracer:
    """Shades ray hits with the shared BRDF, shadow rays and recursion to ``max_bounces``."""

    def __init__(self, trace_scene: TraceScene, snapshot, materials: shading.MaterialTable, textures=None):
        self.scene = trace_scene
        self.snapshot = snapshot
        self.materials = materials
        self.textures = textures or {}
        self.world = np.asarray(snapshot.world_color, dtype=np.float64)
        self.max_bounces = max(int(snapshot.settings.max_bounces), 0)
        self.rays = 0
        self.shadow_rays = 0
        # Rays and shadow rays per batch label (``radiance(..., batch=)``): what each of several
        # batches traced in one call cost, through every bounce.
        self.batch_rays = np.zeros(0)

    def _count(self, batch, rays=None):
        """Add the rays of ``batch`` labels (one per ray) to ``batch_rays``."""
        counts = np.bincount(batch if rays is None else batch[rays])
        if len(counts) > len(self.batch_rays):
            self.batch_rays = np.r_[self.batch_rays, np.zeros(len(counts) - len(self.batch_rays))]
        self.batch_rays[:len(counts)] += counts

    def _albedo(self, material, uv):
        albedo = self.materials.base_color[material]  # a copy (an index array)
        for index, texture in self.textures.items():  # a few textured materials, each once
            chosen = material == index
            if texture is not None and chosen.any():
                albedo[chosen] *= rules.sample_texture(texture, uv[chosen])[:, :3]
        return albedo

    def direct(self, points_trace, surface: shading.SurfaceSamples, view_distance=None, offset_normal=None,
               eps=None, batch=None):
        """Direct light with traced shadows at trace-frame points.  Shadow rays start ``eps``
        (default: ``TraceScene.epsilon`` with ``view_distance``) along ``offset_normal`` (the
        geometric normal on the lit side; default: the shading normal).  ``batch``: a label per
        point, its shadow rays counted in ``batch_rays``."""
        n = len(points_trace)
        lights = self.snapshot.lights
        if n == 0 or not lights:
            return np.zeros((n, 3))
        if eps is None:
            eps = self.scene.epsilon(points_trace, view_distance)
        offset_normal = surface.normal if offset_normal is None else offset_normal
        # Every light at once: one BRDF evaluation and one shadow query over (light, point)
        # pairs, light after light.  Per light, a bounce level of a few rays cost 0.6 ms in
        # numpy and Embree calls (arcade's 5 lights, 7 levels: 70 ms for 349 reflection rays).
        incidence = [shading.light_incidence(light, points_trace, self.scene.origin) for light in lights]
        if len(lights) == 1:
            direction, distance, irradiance = incidence[0]
        else:
            direction = np.concatenate([d for d, _, _ in incidence])
            distance = np.concatenate([d for _, d, _ in incidence])
            irradiance = np.concatenate([e for _, _, e in incidence])
        contribution = shading.brdf_cosine(surface.repeated(len(lights)), direction) * irradiance
        # Lit by some channel (fmax: a NaN channel does not hide the others, as ``any`` would not).
        lit = np.fmax(np.fmax(contribution[:, 0], contribution[:, 1]), contribution[:, 2]) > 0
        casts = [bool(light.cast_shadows) for light in lights]
        if not all(casts):
            lit &= np.repeat(np.array(casts, bool), n)
        test = np.flatnonzero(lit)
        if len(test):
            point = test % n if len(lights) > 1 else test
            start = points_trace[point] + offset_normal[point] * eps[point, None]
            blocked = self.scene.occluded(start, direction[test], distance[test] - 2 * eps[point])
            self.shadow_rays += len(test)
            if batch is not None:
                self._count(batch, point)
            contribution[test[blocked]] = 0.0
        if len(lights) == 1:
            return contribution
        # Summed light after light, as one light at a time added them.
        parts = contribution.reshape(len(lights), n, 3)
        total = parts[0].copy()
        for part in parts[1:]:
            total += part
        return total

    def radiance(self, origins, directions, depth, passed=0, batch=None, weight=1.0):
        """Radiance arriving along trace-frame rays (N,3).  ``depth``: the bounces this ray has
        taken (0 for a camera ray, 1 for a ray leaving the G-buffer), a number or one per ray;
        ``passed``: the surfaces its path has passed straight through; ``batch`` (optional): a
        label per ray (small ints), every ray its path casts counted in ``batch_rays``;
        ``weight``: the path's throughput so far (``PATH_CUTOFF``)."""
        n = len(origins)
        if n == 0:
            return np.broadcast_to(self.world, (0, 3)).copy()
        return self._radiance(np.asarray(origins, dtype=np.float64),
                              np.nan_to_num(np.asarray(directions, dtype=np.float64)),
                              _per_ray(depth, n, np.float64), _per_ray(passed, n, np.int64),
                              None if batch is None else _per_ray(batch, n, np.int64), _per_ray(weight, n, np.float64))

    def _radiance(self, origins, directions, depth, passed, batch, weight):
        """``radiance`` of rays with finite directions and one value per ray of the rest.  A bounce
        level of a few dozen rays costs its numpy calls, not its rays (0.8 ms a level in 80 calls
        before, 1-3 rays a level at the end of arcade's glass paths): whole-array steps only,
        nothing computed for an empty branch."""
        n = len(origins)
        result = np.empty((n, 3))
        result[:] = self.world
        directions = shading.normalize(directions)
        self.rays += n
        if batch is not None:
            self._count(batch)
        hits = self.scene.intersect(origins, directions)
        hit_mask = (hits["geom"] >= 0) & np.isfinite(hits["t"])
        if not hit_mask.any():
            return result
        idx, material, _, normal, geometric, uv, set_index = self.scene.hit_surfaces(hits, hit_mask)
        dirs = directions[idx]
        travelled = hits["t"][idx]
        points = origins[idx] + dirs * travelled[:, None]
        # A degenerate triangle has no geometric normal: use the shading normal, else the ray.
        no_geometric = shading.dot(geometric, geometric) < 0.25
        if no_geometric.any():
            geometric[no_geometric] = normal[no_geometric]
            still = shading.dot(geometric, geometric) < 0.25
            geometric[still] = -dirs[still]
        # Which side: the ray arrives from outside where it opposes the outward normal.
        entering = shading.dot(geometric, dirs) < 0
        side = np.where(entering, 1.0, -1.0)[:, None]
        facing = normal * side
        geometric_facing = geometric * side
        m = self.materials
        surface = shading.SurfaceSamples(
            position=points, normal=facing, view=-dirs, albedo=self._albedo(material, uv),
            metallic=m.metallic[material], roughness=m.roughness[material],
            transmission=m.transmission[material], ior=m.ior[material], emission=m.emission[material])
        eps = self.scene.epsilon(points, travelled, set_index=set_index)
        batch = None if batch is None else batch[idx]
        color = surface.emission + self.direct(points, surface, offset_normal=geometric_facing, eps=eps, batch=batch)
        diffuse_ambient, env_fresnel = shading.ambient(surface, self.world)
        color += diffuse_ambient
        transmissive = m.transmissive[material]
        # Dielectric Fresnel for the transmissive part (exact, with total internal reflection).
        eta = np.where(entering, 1.0 / surface.ior, surface.ior)
        cos_i = shading.unit_clip(shading.dot(surface.view, facing))
        fresnel_t = shading.fresnel_dielectric(cos_i, 1.0 / eta)
        reflect_weight = env_fresnel * (1.0 - transmissive)[:, None] + (transmissive * fresnel_t)[:, None]
        blend = reflection_blend(surface.roughness)
        depth = depth[idx]
        passed = passed[idx]
        weight = weight[idx]
        can_bounce = depth < self.max_bounces
        transmits = transmissive > rules.TRANSPARENT_EPSILON
        # Total internal reflection: nothing is refracted, and the bounce costs only
        # TIR_BOUNCE_COST, so light entering a glass side face can get out again.
        total_internal = transmits & (fresnel_t >= 1.0)
        next_depth = depth + np.where(total_internal, TIR_BOUNCE_COST, 1.0)
        reflect_largest = shading.largest(reflect_weight)
        reflect_path = weight * blend * reflect_largest
        trace_reflection = can_bounce & (blend > 0) & (reflect_largest > 0.02) & (reflect_path >= PATH_CUTOFF)
        refracts = transmits & ~total_internal
        tint = np.where(entering[:, None], surface.albedo, 1.0)
        refract_weight = (transmissive * (1.0 - fresnel_t))[:, None] * tint
        refract_path = weight * shading.largest(refract_weight)
        trace_refraction = can_bounce & refracts & (refract_path >= PATH_CUTOFF)
        world_through = np.flatnonzero(can_bounce & refracts & ~trace_refraction)  # too faint: the world colour
        # Straight on, unbent: the 1 - alpha part of the surface, and the transmitted part of a
        # transmissive surface out of bounces (the raster's blended transparency).
        alpha = m.alpha[material][:, None]
        straight_weight = (1.0 - alpha) + alpha * np.where((refracts & ~can_bounce)[:, None], refract_weight, 0.0)
        straight = np.flatnonzero(shading.largest(straight_weight) > 0)
        straight_path = weight[straight] * shading.largest(straight_weight[straight])
        more = (passed[straight] < MAX_PASS_THROUGH) & (straight_path >= PATH_CUTOFF)

        # Every secondary ray of this batch (reflected, refracted, passing straight on) is traced
        # in one call: one Embree query and one hit shading per bounce level, not per branch.
        r = np.flatnonzero(trace_reflection)
        t = np.flatnonzero(trace_refraction)
        s = straight[more]
        traced = through = passing = np.zeros((0, 3))
        if len(r) + len(t) + len(s):
            reflect_direction = leave_surface(shading.reflect(dirs[r], facing[r]), geometric_facing[r]) \
                if len(r) else dirs[r]
            refract_direction = leave_surface(shading.refract(dirs[t], facing[t], eta[t])[0], geometric_facing[t],
                                              side=-1.0) if len(t) else dirs[t]
            # Reflections leave on the lit side, the rest on the other.
            order = np.concatenate([r, t, s])
            away = eps[order]
            away[len(r):] *= -1.0
            secondary = self._radiance(
                points[order] + geometric_facing[order] * away[:, None],
                np.concatenate([reflect_direction, refract_direction, dirs[s]]),
                np.concatenate([next_depth[r], next_depth[t], depth[s]]),
                np.concatenate([passed[r], passed[t], passed[s] + 1]),
                None if batch is None else batch[order],
                np.concatenate([reflect_path[r], refract_path[t], straight_path[more]]))
            traced, through, passing = secondary[:len(r)], secondary[len(r):len(r) + len(t)], secondary[len(r) + len(t):]
        if len(r):
            reflected = np.empty((len(idx), 3))
            reflected[:] = self.world
            reflected[r] = blend[r, None] * traced + (1.0 - blend[r, None]) * self.world
            color += reflect_weight * reflected
        else:
            color += reflect_weight * self.world
        if len(t):
            color[t] += refract_weight[t] * through
        if len(world_through):
            color[world_through] += refract_weight[world_through] * self.world
        color *= alpha
        if len(straight):
            behind = np.empty((len(straight), 3))
            behind[:] = self.world
            behind[more] = passing
            color[straight] += straight_weight[straight] * behind
        result[idx] = shading.finite(color)
        return result


def _per_ray(value, n, dtype):
    """``value`` (a number or one per ray) as one per ray of ``dtype``."""
    value = np.asarray(value, dtype=dtype)
    return value if value.shape == (n,) else np.broadcast_to(value, (n,))
