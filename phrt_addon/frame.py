"""One PHRT frame after the G-buffer: selection, ray tracing, compositing.

``FrameRenderer`` lives for a whole replay (one per engine instance or CLI run):
it keeps the Embree scenes, the cost model and last frame's selection (the
paper's S).  ``render()`` takes a snapshot, its G-buffer and the shadow maps
and returns every pass plus the statistics and selection rows of the logs.

Stages (CONTRACT.md section 4 timings):
- raster_ms   (measured by the caller: GPU G-buffer + read-back + shadow maps) plus
              the shadow-map lookups done here;
- select_ms   element statistics from the element-id image and the heuristic;
- trace_ms    Embree upload of changed geometry, shadow / reflection / refraction rays;
- composite_ms deferred lighting with the final visibility and blending of the
              traced and raster terms into the passes.

Pay only for what is used: RASTER never touches the tracer (``embreex`` is not
even imported), no lights means no shadow work, and no selected element means
no Embree work at all.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from . import heuristic, rules, shading
from .cost_model import CostModel, FrameStats
from .gbuffer import GBuffer, element_pixel_stats, geometric_normals
from .problems import ProblemLog
from .scene import SceneSnapshot, transform_points
from .shadowmap import shadow_visibility

# Pixel sub-sampling step used to estimate each element's shadow footprint for the cost model.
FOOTPRINT_STEP = 8


@dataclass
class FramePasses:
    combined: np.ndarray  # (h,w,4) float32, linear, alpha 1 where covered or world
    depth: np.ndarray  # (h,w) float32 view-axis distance; large where background
    normal: np.ndarray  # (h,w,3) float32
    selected: np.ndarray  # (h,w) float32, 1 where the front element was ray traced
    candidate: np.ndarray  # (h,w) float32, 1 on candidate elements' pixels


@dataclass
class FrameResult:
    passes: FramePasses
    stats: dict
    selection: object
    selection_rows: list
    problems: list = field(default_factory=list)


# Below this many pixels per task, threads cost more than they save.
PARALLEL_MIN_PIXELS = 20000
_POOL = None


def _map(function, items, pixels):
    """``[function(item) for item in items]``, on a thread pool when the work is large enough
    (numpy releases the GIL in its whole-array loops, so lights shade in parallel)."""
    global _POOL
    if len(items) < 2 or pixels < PARALLEL_MIN_PIXELS:
        return [function(item) for item in items]
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor
        from .tracer import worker_count
        _POOL = ThreadPoolExecutor(worker_count(), thread_name_prefix="phrt-shade")
    return list(_POOL.map(function, items))


def _timer():
    return time.perf_counter()


def _ms(start):
    return (time.perf_counter() - start) * 1000.0


class FrameRenderer:
    """Renders the frames of one replay, carrying state from frame to frame."""

    def __init__(self, threads: int | None = None):
        self.threads = threads
        self.cost_model = None
        self.previous_selection = {}
        self.trace_scene = None
        self.frames_rendered = 0
        self.problems = ProblemLog()  # what this replay's snapshots skipped or approximated (engine/final.py)

    def close(self):
        if self.trace_scene is not None:
            self.trace_scene.close()
            self.trace_scene = None

    # ------------------------------------------------------------------
    def render(self, snapshot: SceneSnapshot, gbuffer: GBuffer, shadow_maps: dict, raster_ms: float,
               raster_setup_ms: float = 0.0) -> FrameResult:
        """``raster_setup_ms``: the one-time part of ``raster_ms`` (shader compiles, shadow maps drawn
        anew): reported, but not taught to the cost model as a per-frame cost."""
        settings = snapshot.settings
        mode = settings.mode.upper()
        height, width = gbuffer.height, gbuffer.width
        materials = shading.MaterialTable(snapshot.materials)
        if self.cost_model is None:
            self.cost_model = CostModel()

        # -- raster shadows (shadow-map lookups) ------------------------------
        start = _timer()
        layers = self._layer_samples(gbuffer, snapshot, materials)
        # Per layer and light: the pixels the light reaches (facing it, non-negligible irradiance),
        # its direction and irradiance there, and their visibility (shadow maps now, rays later).
        # Lights are independent and numpy releases the GIL on whole arrays: one task per light.
        visibility = {}
        for layer_name, samples in layers.items():
            visibility[layer_name] = _map(lambda item: light_terms(item[1], samples, shadow_maps.get(item[0])),
                                          list(enumerate(snapshot.lights)), len(samples["world"]))
        raster_ms = raster_ms + _ms(start)

        # -- selection --------------------------------------------------------
        start = _timer()
        n_elements = len(snapshot.elements)
        front = gbuffer.front_element()
        area_px, centre_ndc, distance = element_pixel_stats(front, n_elements, gbuffer.view_depth)
        shadow_lights = [light for light in snapshot.lights if light.cast_shadows]
        element_bounds = _element_bounds(snapshot)
        footprint = self._shadow_footprints(layers, snapshot, element_bounds, area_px, mode) \
            if shadow_lights and mode != "RASTER" else np.zeros(n_elements)
        frame_elements = heuristic.FrameElements(
            names=[e.name for e in snapshot.elements],
            candidate=np.array([e.is_candidate for e in snapshot.elements], bool),
            area_px=area_px, centre_ndc=centre_ndc, distance=distance,
            priority=np.array([e.priority for e in snapshot.elements], float),
            rt_cost=np.array([e.rt_cost for e in snapshot.elements], float),
            shadows=np.array([e.shadows for e in snapshot.elements], bool),
            reflections=np.array([e.reflections for e in snapshot.elements], bool),
            refractions=np.array([e.refractions for e in snapshot.elements], bool),
            rays_per_pixel=_rays_per_pixel(snapshot, area_px, footprint, settings.max_bounces),
            frame_px=width * height,
            near_clip=snapshot.camera.clip_start,
        )
        selection = heuristic.select(
            frame_elements, self.previous_selection,
            heuristic.SelectionSettings(budget_ms=settings.budget_ms, selection_weight=settings.selection_weight,
                                        max_area_fraction=settings.max_area_fraction, mode=mode,
                                        cost_mode=settings.cost_mode),
            self.cost_model, frame=snapshot.frame)
        selected = np.asarray(selection.selected, bool)
        select_ms = _ms(start)

        # -- ray tracing ------------------------------------------------------
        start = _timer()
        counters = _Counters()
        reflection_radiance = {}
        refraction_radiance = {}
        element_rays = np.zeros(n_elements)
        if np.any(selected):
            self._trace(snapshot, gbuffer, layers, materials, selected, element_bounds, visibility,
                        reflection_radiance, refraction_radiance, counters, element_rays)
        trace_ms = _ms(start)

        # -- compositing --------------------------------------------------------
        start = _timer()
        passes = self._composite(snapshot, gbuffer, layers, materials, visibility, reflection_radiance,
                                 refraction_radiance, selected)
        composite_ms = _ms(start)

        total_ms = raster_ms + select_ms + trace_ms + composite_ms
        # One-time work (Embree builds, shader compiles, new shadow maps) is not a per-frame cost.
        self.cost_model.observe(FrameStats(
            raster_ms=max(raster_ms - raster_setup_ms, 0.0), select_ms=select_ms, composite_ms=composite_ms,
            trace_ms=max(trace_ms - counters.upload_ms, 0.0) if np.any(selected) else None,
            effect_ms={"shadows": counters.shadow_ms, "reflections": counters.reflection_ms,
                       "refractions": counters.refraction_ms},
            effect_rays={"shadows": counters.shadow_rays, "reflections": counters.reflection_rays,
                         "refractions": counters.refraction_rays},
            element_rays=element_rays), selection)
        self.previous_selection = {name: bool(flag) for name, flag in zip(frame_elements.names, selected)}
        self.frames_rendered += 1
        stats = {
            "frame": snapshot.frame, "mode": mode, "total_ms": total_ms, "raster_ms": raster_ms,
            "select_ms": select_ms, "trace_ms": trace_ms, "composite_ms": composite_ms,
            "budget_ms": settings.budget_ms, "predicted_trace_ms": float(selection.predicted_trace_ms),
            "n_candidates": int(np.sum(frame_elements.candidate)),
            "n_visible": int(np.sum(np.asarray(selection.visible, bool))),
            "n_selected": int(np.sum(selected)), "rays": counters.rays,
            "shadow_rays": counters.shadow_rays, "reflection_rays": counters.reflection_rays,
            "refraction_rays": counters.refraction_rays, "upload_ms": counters.upload_ms,
            "setup_ms": raster_setup_ms + counters.upload_ms,
            "time_left_ms": float(selection.time_left_ms), "triangles": snapshot.n_triangles,
        }
        return FrameResult(passes=passes, stats=stats, selection=selection,
                           selection_rows=selection.rows(snapshot.frame), problems=list(snapshot.problems))

    # ------------------------------------------------------------------
    @staticmethod
    def _layer_samples(gbuffer, snapshot, materials):
        """Per covered pixel of each layer: flat index, world point (float64, for rays),
        and float32 surface samples relative to the camera (for deferred lighting)."""
        camera = snapshot.camera
        layers = {}
        for name, layer in (("opaque", gbuffer.opaque), ("transparent", gbuffer.transparent)):
            flat = np.flatnonzero(layer.covered.ravel())
            position = layer.position.reshape(-1, 3)[flat]  # float32, camera-relative
            world = position.astype(np.float64) + gbuffer.origin
            # Positions are relative to the camera: the view ray is the position itself
            # (perspective) or the camera axis (orthographic).
            if camera.ortho:
                view_dirs = np.broadcast_to(camera.forward.astype(np.float32), position.shape).copy()
            else:
                view_dirs = shading.normalize(position)
            material = np.clip(layer.material.ravel()[flat], 0, len(materials.ior) - 1)
            normal = shading.normalize(layer.normal.reshape(-1, 3)[flat])
            # A normal facing away from the viewer (interpolation at silhouettes) is flipped.
            back = shading.dot(normal, view_dirs) > 0
            normal[back] *= -1.0
            surface = shading.SurfaceSamples(
                position=position, normal=normal, view=-view_dirs,
                albedo=layer.albedo.reshape(-1, 3)[flat],
                metallic=layer.metallic.ravel()[flat],
                roughness=layer.roughness.ravel()[flat],
                transmission=materials.transmission[material].astype(np.float32),
                ior=materials.ior[material].astype(np.float32),
                emission=materials.emission[material].astype(np.float32))
            layers[name] = {"name": name, "flat": flat, "world": world, "surface": surface, "material": material,
                            "element": layer.element.ravel()[flat], "directions": view_dirs,
                            "origin": gbuffer.origin}
        return layers

    def _shadow_footprints(self, layers, snapshot, element_bounds, area_px, mode):
        """Estimated shadow-ray count per element (pixels it can shadow, summed over lights),
        from a 1/FOOTPRINT_STEP^2 sub-sample of the opaque layer."""
        n = len(snapshot.elements)
        footprint = np.zeros(n)
        samples = layers["opaque"]
        if len(samples["world"]) == 0:
            return footprint
        points = samples["world"][::FOOTPRINT_STEP * FOOTPRINT_STEP]
        scale = FOOTPRINT_STEP * FOOTPRINT_STEP
        casters = [index for index, element in enumerate(snapshot.elements)
                   if element.is_candidate and element.shadows and area_px[index] > 0
                   and element_bounds[index] is not None]
        for light in snapshot.lights:
            if not light.cast_shadows or not casters:
                continue
            light_index = ShadowRegionIndex(light, points)
            for index in casters:
                footprint[index] += scale * np.count_nonzero(light_index.region(element_bounds[index]))
        return footprint

    # ------------------------------------------------------------------
    def _trace(self, snapshot, gbuffer, layers, materials, selected, element_bounds, visibility,
               reflection_radiance, refraction_radiance, counters, element_rays):
        from .tracer import RadianceTracer, TraceScene, leave_surface, reflection_blend

        if self.trace_scene is None:
            self.trace_scene = TraceScene(self.threads)
        counters.upload_ms = self.trace_scene.update(snapshot, materials.casts_shadow[:len(snapshot.materials)])
        scene = self.trace_scene
        textures = {index: prepared_texture(m.texture) for index, m in enumerate(snapshot.materials)
                    if m.texture is not None}
        tracer = RadianceTracer(scene, snapshot, materials, textures)
        elements = snapshot.elements
        layer_of = {"opaque": gbuffer.opaque, "transparent": gbuffer.transparent}

        def ray_start(samples, idx):
            """Trace-frame points, their geometric normals facing the camera and ray offsets."""
            points_trace = scene.to_trace(samples["world"][idx])  # only the pixels that get rays
            normal = geometric_normals(layer_of[samples["name"]], samples["flat"][idx], samples["directions"][idx])
            eps = scene.epsilon(points_trace, _camera_distance(samples, idx), element=samples["element"][idx])
            return points_trace, normal, eps

        # Shadows: for each light, the pixels a selected shadow caster can shadow get traced visibility.
        start = _timer()
        casters = [i for i in np.flatnonzero(selected) if elements[i].shadows and element_bounds[i] is not None]
        for layer_name, samples in layers.items():
            if not casters or len(samples["world"]) == 0:
                continue
            for light_index, light in enumerate(snapshot.lights):
                terms = visibility[layer_name][light_index]
                if not light.cast_shadows or len(terms.active) == 0:
                    continue
                index = ShadowRegionIndex(light, samples["world"][terms.active])
                region = np.zeros(len(terms.active), bool)
                for caster in casters:
                    caster_region = index.region(element_bounds[caster])
                    element_rays[caster] += np.count_nonzero(caster_region)
                    region |= caster_region
                local = np.flatnonzero(region)
                if len(local) == 0:
                    continue
                idx = terms.active[local]
                points_trace, normal, eps = ray_start(samples, idx)
                _, distance, _ = shading.light_incidence(light, points_trace, scene.origin)
                origins = points_trace + normal * eps[:, None]
                blocked = scene.occluded(origins, terms.direction[local], distance - 2 * eps)
                terms.visibility[local] = np.where(blocked, 0.0, 1.0)
                counters.shadow_rays += len(idx)
        counters.shadow_ms = _ms(start)
        # Reflections and refractions are bounces: none with max_bounces 0 (the raster result stays).
        bounces = int(snapshot.settings.max_bounces) >= 1

        # Reflections on selected elements' pixels (mirror direction, blended by roughness).
        start = _timer()
        rays_before = tracer.rays + tracer.shadow_rays
        for layer_name, samples in layers.items():
            if not bounces:
                break
            surface = samples["surface"]
            element_of = samples["element"]
            wanted = np.zeros(len(element_of), bool)
            for index in np.flatnonzero(selected):
                if elements[index].reflections:
                    wanted |= element_of == index
            wanted &= reflection_blend(surface.roughness) > 0
            idx = np.flatnonzero(wanted)
            if len(idx) == 0:
                continue
            points_trace, normal, eps = ray_start(samples, idx)
            direction = leave_surface(shading.reflect(samples["directions"][idx], surface.normal[idx]), normal)
            radiance = tracer.radiance(points_trace + normal * eps[:, None], direction, 1)
            reflection_radiance[layer_name] = (idx, radiance)
            np.add.at(element_rays, element_of[idx], 1)
        counters.reflection_rays = tracer.rays + tracer.shadow_rays - rays_before
        counters.reflection_ms = _ms(start)

        # Refractions through selected transparent elements (transparent layer only).
        start = _timer()
        rays_before = tracer.rays + tracer.shadow_rays
        samples = layers["transparent"]
        if bounces and len(samples["world"]):
            surface = samples["surface"]
            element_of = samples["element"]
            wanted = np.zeros(len(element_of), bool)
            for index in np.flatnonzero(selected):
                if elements[index].refractions:
                    wanted |= element_of == index
            wanted &= materials.transmissive[samples["material"]] > rules.TRANSPARENT_EPSILON
            idx = np.flatnonzero(wanted)
            if len(idx):
                points_trace, normal, eps = ray_start(samples, idx)
                direction, _ = shading.refract(samples["directions"][idx], surface.normal[idx], 1.0 / surface.ior[idx])
                direction = leave_surface(direction, normal, side=-1.0)
                radiance = tracer.radiance(points_trace - normal * eps[:, None], direction, 1)
                refraction_radiance["transparent"] = (idx, radiance)
                np.add.at(element_rays, element_of[idx], 1)
        counters.refraction_rays = tracer.rays + tracer.shadow_rays - rays_before
        counters.refraction_ms = _ms(start)

    # ------------------------------------------------------------------
    def _composite(self, snapshot, gbuffer, layers, materials, visibility, reflection_radiance,
                   refraction_radiance, selected):
        height, width = gbuffer.height, gbuffer.width
        world = np.asarray(snapshot.world_color, dtype=np.float64)
        shaded = {}
        for layer_name, samples in layers.items():
            surface = samples["surface"]
            color = surface.emission.copy()
            def contribution(terms, surface=surface):
                weight = terms.irradiance * terms.visibility[:, None]
                return terms.active, shading.brdf_cosine(surface.subset(terms.active), terms.direction) * weight

            lit_terms = [terms for terms in visibility[layer_name] if len(terms.active)]
            for lit, light_color in _map(contribution, lit_terms, len(surface)):
                color[lit] += light_color
            diffuse_ambient, fresnel = shading.ambient(surface, world)
            color += diffuse_ambient
            transmissive = surface.transmission * (1.0 - surface.metallic)
            reflected = np.broadcast_to(world, color.shape).copy()
            if layer_name in reflection_radiance:
                from .tracer import reflection_blend
                idx, radiance = reflection_radiance[layer_name]
                blend = reflection_blend(surface.roughness[idx])[:, None]
                reflected[idx] = blend * radiance + (1.0 - blend) * world
            cos_v = np.clip(np.sum(surface.normal * surface.view, axis=1), 0.0, 1.0)
            fresnel_t = shading.fresnel_dielectric(cos_v, surface.ior)
            reflect_weight = fresnel * (1.0 - transmissive)[:, None] + (transmissive * fresnel_t)[:, None]
            color += reflect_weight * reflected
            shaded[layer_name] = (color, transmissive, fresnel_t)

        image = np.broadcast_to(world, (height * width, 3)).copy()
        opaque = layers["opaque"]
        image[opaque["flat"]] = shaded["opaque"][0]
        transparent = layers["transparent"]
        if len(transparent["flat"]):
            color, transmissive, fresnel_t = shaded["transparent"]
            surface = transparent["surface"]
            behind = image[transparent["flat"]].copy()  # raster: straight through, no bending
            refracted = behind.copy()  # the transmissive part: bent where traced
            if "transparent" in refraction_radiance:
                idx, radiance = refraction_radiance["transparent"]
                refracted[idx] = radiance
            tint = surface.albedo
            transmitted = (transmissive * (1.0 - fresnel_t))[:, None] * tint * refracted
            alpha = materials.alpha[transparent["material"]][:, None]
            surface_color = color + transmitted
            # The 1 - alpha part goes straight on (as the tracer's pass-through does).
            image[transparent["flat"]] = alpha * surface_color + (1.0 - alpha) * behind
        image = shading.finite(image).reshape(height, width, 3)

        combined = np.ones((height, width, 4), np.float32)
        combined[..., :3] = image
        front = gbuffer.front_element()
        candidate_flags = np.array([e.is_candidate for e in snapshot.elements] + [False], bool)
        selected_flags = np.r_[np.asarray(selected, bool), False]
        depth = np.where(np.isfinite(gbuffer.view_depth), gbuffer.view_depth, 1e10).astype(np.float32)
        return FramePasses(
            combined=combined,
            depth=depth,
            normal=np.nan_to_num(gbuffer.front_normal()).astype(np.float32),
            selected=selected_flags[front].astype(np.float32),
            candidate=candidate_flags[front].astype(np.float32),
        )


@dataclass
class _Counters:
    shadow_rays: int = 0
    reflection_rays: int = 0
    refraction_rays: int = 0
    shadow_ms: float = 0.0
    reflection_ms: float = 0.0
    refraction_ms: float = 0.0
    upload_ms: float = 0.0

    @property
    def rays(self):
        return self.shadow_rays + self.reflection_rays + self.refraction_rays


_PREPARED = {}  # id(texture) -> (texture, prepared): prepared once per image, not per frame


def prepared_texture(texture):
    """``rules.prepare_texture`` of a snapshot's texture, cached while the image lives."""
    entry = _PREPARED.get(id(texture))
    if entry is None or entry[0] is not texture:
        if len(_PREPARED) > 64:
            _PREPARED.clear()
        entry = _PREPARED[id(texture)] = (texture, rules.prepare_texture(texture))
    return entry[1]


def _camera_distance(samples, index=slice(None)):
    """Distance from the camera of G-buffer points (their positions are camera-relative): the
    size of their float32 error, which secondary-ray offsets must exceed (telephoto views)."""
    position = samples["surface"].position[index]
    return np.sqrt(shading.dot(position, position))


# Pixels receiving less than this fraction of a light's strongest irradiance in the frame skip it.
LIGHT_CUTOFF = 1e-4


@dataclass
class LightTerms:
    """One light at the pixels of one G-buffer layer it reaches."""

    active: np.ndarray  # indices of the pixels facing the light with non-negligible irradiance
    direction: np.ndarray  # (n_active, 3) unit, towards the light
    irradiance: np.ndarray  # (n_active, 3)
    visibility: np.ndarray  # (n_active,) lit fraction: shadow map, replaced by rays where traced


def light_terms(light, samples, shadow_maps) -> LightTerms:
    """Direction, irradiance and raster (shadow-map) visibility of ``light`` where it matters."""
    surface = samples["surface"]
    if len(surface) == 0:
        empty = np.zeros((0, 3))
        return LightTerms(np.zeros(0, np.int64), empty, empty, np.zeros(0))
    direction, _, irradiance = shading.light_incidence(light, surface.position, samples["origin"])
    strength = irradiance.max(axis=1)
    reached = (shading.dot(surface.normal, direction) > 0) & (strength > LIGHT_CUTOFF * max(strength.max(), 1e-30))
    active = np.flatnonzero(reached)
    direction = np.ascontiguousarray(direction[active])
    irradiance = np.ascontiguousarray(irradiance[active])
    if light.cast_shadows and shadow_maps and len(active):
        visibility = shadow_visibility(shadow_maps, surface.position[active], surface.normal[active],
                                       origin=samples["origin"])
    else:
        visibility = np.ones(len(active), np.float32)
    return LightTerms(active, direction, irradiance, visibility)


_LOCAL_BOUNDS = {}  # geometry key -> {element: (low, high)} in local space (static per replay)


def _local_element_bounds(mesh):
    cached = _LOCAL_BOUNDS.get(mesh.geometry_key)
    if cached is None:
        cached = {}
        corners = mesh.positions[mesh.triangles]  # (T, 3, 3)
        low = corners.min(axis=1)
        high = corners.max(axis=1)
        for element in np.unique(mesh.tri_element[mesh.tri_element >= 0]):
            chosen = mesh.tri_element == element
            cached[int(element)] = (low[chosen].min(axis=0).astype(np.float64),
                                    high[chosen].max(axis=0).astype(np.float64))
        if len(_LOCAL_BOUNDS) > 4096:
            _LOCAL_BOUNDS.clear()
        _LOCAL_BOUNDS[mesh.geometry_key] = cached
    return cached


def _element_bounds(snapshot):
    """World-space (min, max) of each element (None when it has no triangles): the local
    bounds (cached per geometry) with their 8 corners moved by the world matrix."""
    bounds = [None] * len(snapshot.elements)
    signs = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=np.float64)
    for mesh in snapshot.meshes:
        if mesh.n_triangles == 0:
            continue
        for element, (low, high) in _local_element_bounds(mesh).items():
            corners = transform_points(mesh.matrix_world, low + signs * (high - low))
            world_low, world_high = corners.min(axis=0), corners.max(axis=0)
            if bounds[element] is None:
                bounds[element] = (world_low, world_high)
            else:
                bounds[element] = (np.minimum(bounds[element][0], world_low),
                                   np.maximum(bounds[element][1], world_high))
    return bounds


def shadow_region(light, bounds, points) -> np.ndarray:
    """Points (world, (N,3)) whose segment to ``light`` may pass through the box ``bounds``:
    the pixels an element can shadow.  Conservative (a bounding sphere or a light-space box)."""
    low, high = bounds
    centre = (low + high) / 2.0
    radius = 0.5 * float(np.linalg.norm(high - low)) + 1e-6
    if light.kind == "SUN":
        direction = shading.normalize(np.asarray(light.direction, dtype=np.float64))
        relative = points - centre
        along = relative @ direction  # > 0: downstream of the caster
        lateral = relative - along[:, None] * direction
        return (along > -radius) & (np.einsum("ij,ij->i", lateral, lateral) <= radius * radius)
    light_position = np.asarray(light.position, dtype=np.float64)
    to_centre = centre - light_position
    centre_distance = float(np.linalg.norm(to_centre))
    if centre_distance <= radius:
        return np.ones(len(points), bool)  # the light is inside the caster's bounds
    axis = to_centre / centre_distance
    to_point = points - light_position
    point_distance = np.linalg.norm(to_point, axis=1)
    cos_point = (to_point @ axis) / np.maximum(point_distance, 1e-30)
    cos_cone = np.sqrt(max(1.0 - (radius / centre_distance) ** 2, 0.0))
    return (cos_point >= cos_cone) & (point_distance > centre_distance - radius)


class ShadowRegionIndex:
    """``shadow_region`` for many casters and one light over the same points.

    The points' light-space coordinates are computed once per light: for the sun, two
    coordinates across the light and one along it; for local lights, the unit direction
    from the light and the distance.  A caster is then a few float32 operations per point.
    Once a light has ``SORT_AFTER_QUERIES`` casters, the points are also sorted by one
    coordinate, and each further caster tests only the window of points that can be in
    its cylinder or cone (a searchsorted range).  Same answer as ``shadow_region``."""

    SORT_AFTER_QUERIES = 6

    def __init__(self, light, points):
        self.light = light
        points = np.asarray(points, dtype=np.float64)
        self.n = len(points)
        self.queries = 0
        self.order = None
        if light.kind == "SUN":
            direction = shading.normalize(np.asarray(light.direction, dtype=np.float64))
            helper = np.array([1.0, 0.0, 0.0]) if abs(direction[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
            across = shading.normalize(np.cross(direction, helper))
            self.basis = np.stack([across, np.cross(direction, across), direction])
            self.coords = (points @ self.basis.T).astype(np.float32)  # (u, v) across, w along
        else:
            self.origin = np.asarray(light.position, dtype=np.float64)
            to_point = points - self.origin
            distance = np.sqrt(shading.dot(to_point, to_point))
            self.coords = np.concatenate([to_point / np.maximum(distance, 1e-30)[:, None], distance[:, None]],
                                         axis=1).astype(np.float32)  # unit direction, distance

    def _test(self, coords, bounds):
        low, high = bounds
        centre = (low + high) / 2.0
        radius = 0.5 * float(np.linalg.norm(high - low)) + 1e-6
        if self.light.kind == "SUN":
            cu, cv, cw = self.basis @ centre
            du = coords[:, 0] - np.float32(cu)
            dv = coords[:, 1] - np.float32(cv)
            return (du * du + dv * dv <= np.float32(radius * radius)) & (coords[:, 2] > np.float32(cw - radius))
        to_centre = centre - self.origin
        distance = float(np.linalg.norm(to_centre))
        if distance <= radius:
            return np.ones(len(coords), bool)  # the light is inside the caster's bounds
        axis = (to_centre / distance).astype(np.float32)
        cos_cone = np.float32(np.sqrt(max(1.0 - (radius / distance) ** 2, 0.0)))
        return (coords[:, :3] @ axis >= cos_cone) & (coords[:, 3] > np.float32(distance - radius))

    def _window(self, bounds):
        """The index range of sorted points that may pass ``_test`` (a superset)."""
        low, high = bounds
        centre = (low + high) / 2.0
        radius = 0.5 * float(np.linalg.norm(high - low)) + 1e-6
        if self.light.kind == "SUN":
            key = float(self.basis[0] @ centre)
            reach = radius
        else:
            to_centre = centre - self.origin
            distance = float(np.linalg.norm(to_centre))
            if distance <= radius:
                return 0, self.n
            # Unit directions within the cone's half angle t of the axis a satisfy |d_x - a_x| <= t.
            key = to_centre[0] / distance
            reach = float(np.arcsin(min(radius / distance, 1.0)))
        margin = 1e-5 * (abs(key) + reach) + 1e-6  # float32 keys
        start = np.searchsorted(self.sorted_key, key - reach - margin, side="left")
        stop = np.searchsorted(self.sorted_key, key + reach + margin, side="right")
        return start, stop

    def region(self, bounds) -> np.ndarray:
        self.queries += 1
        if self.queries <= self.SORT_AFTER_QUERIES:
            return self._test(self.coords, bounds)
        if self.order is None:
            self.order = np.argsort(self.coords[:, 0], kind="stable")
            self.sorted_key = self.coords[self.order, 0]
            self.sorted_coords = self.coords[self.order]
        start, stop = self._window(bounds)
        result = np.zeros(self.n, bool)
        result[self.order[start:stop]] = self._test(self.sorted_coords[start:stop], bounds)
        return result


def _rays_per_pixel(snapshot, area_px, footprint, max_bounces):
    """Rays one pixel of each element costs with its effects (input of the measured cost model).
    Reflections and refractions are bounces: none with ``max_bounces`` 0."""
    rays = np.zeros(len(snapshot.elements))
    safe_area = np.maximum(area_px, 1)
    bounces = int(max_bounces) >= 1
    for index, element in enumerate(snapshot.elements):
        per_pixel = 0.0
        if element.shadows:
            per_pixel += footprint[index] / safe_area[index]
        if element.reflections and bounces:
            per_pixel += 1.0 + len(snapshot.lights)  # the reflection ray and its hit's shadow rays
        if element.refractions and bounces:
            per_pixel += 2.0 + len(snapshot.lights)  # in, out, and the hit's shadow rays
        rays[index] = per_pixel
    return rays
