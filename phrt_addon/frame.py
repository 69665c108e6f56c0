"""One PHRT frame after the G-buffer: selection, ray tracing, then lighting and composite.

``FrameRenderer`` lives for a whole replay (one per engine instance or CLI run):
it keeps the Embree scenes, the cost model and last frame's selection (the
paper's S).  ``render()`` takes a snapshot and a ``RasterFrame`` whose G-buffer
is already drawn, and returns every pass plus the statistics and selection rows
of the logs.

A ``RasterFrame`` is the raster half: ``engine/raster.GPUFrame`` (GLSL on Blender's
``gpu`` module) in the engine, ``lighting.ReferenceRaster`` (numpy, the same
equations) in core tests.  It provides the front element ids, view depth and
normal (read back after the G-buffer), the full layers on request (only when
rays will be traced), and ``shade(traced)``: deferred lighting and composite,
with the tracer's results where it replaced the raster ones.

Stages (the columns of frames.csv, docs/formats.md):
- raster_ms     G-buffer, its read-back, shadow maps (re-rendered only after a change),
                and in HYBRID/RAYTRACE the layers read back for rays;
- select_ms     element statistics from the element-id image and the heuristic;
- trace_ms      Embree upload of changed geometry, shadow / reflection / refraction rays,
                shading of the ray hits, and the upload of their results to the GPU;
- composite_ms  the deferred lighting passes, composite and read-back of the image.

Pay only for what is used: RASTER never touches the tracer (``embreex`` is not
even imported) nor reads the layers back, no lights means no shadow work, and no
selected element means no Embree work at all.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from . import benefit, heuristic, rules, shading
from .cost_model import CostModel, FrameStats
from .gbuffer import GBuffer, element_pixel_stats, geometric_normals
from .problems import ProblemLog
from .scene import SceneSnapshot
from .shadow_region import ElementBounds, ShadowRegionIndex

# Pixel sub-sampling step used to estimate each element's shadow footprint for the cost model.
FOOTPRINT_STEP = 8


class RasterFrame(Protocol):
    width: int
    height: int
    raster_ms: float  # G-buffer drawn and read back, shadow maps included
    setup_ms: float  # the one-time part of raster_ms (compiles, uploads, new shadow maps)
    front_element: np.ndarray  # (h, w) int, -1 where no element
    view_depth: np.ndarray  # (h, w) float32 distance along the view axis; inf = background
    front_normal: np.ndarray  # (h, w, 3) float32
    stats: dict

    def gbuffer(self) -> GBuffer: ...

    def shade(self, traced: "TracedTerms | None", measure_change: bool = False) -> np.ndarray | None: ...

    def traced_change(self) -> np.ndarray:
        """(h, w, 4) after ``shade(..., measure_change=True)``: per pixel, the luminance (clipped
        to [0, 1]) of what the traced reflections and refractions (x) and the traced shadows (y)
        changed against the raster image."""


@dataclass
class TracedTerms:
    """What the trace stage computed, by flat pixel index (row 0 at the bottom)."""

    # (layer, light index) -> (pixels, lit fraction): replaces the shadow map there
    shadow_visibility: dict = field(default_factory=dict)
    # layer -> (pixels, (n, 3) radiance reflected towards the viewer, blended by roughness)
    reflection: dict = field(default_factory=dict)
    # (pixels, (n, 3) radiance arriving through the transparent layer), or None
    refraction: tuple | None = None


@dataclass
class FramePasses:
    combined: np.ndarray | None  # (h,w,4) float32, linear, alpha 1; None if left on the GPU
    depth: np.ndarray  # (h,w) float32 view-axis distance; 1e10 where background
    normal: np.ndarray  # (h,w,3) float32
    selected: np.ndarray  # (h,w) float32, 1 where the front element was ray traced
    candidate: np.ndarray  # (h,w) float32, 1 on candidate elements' pixels
    element: np.ndarray | None = None  # (h,w) float32, front element index + 1 (0: none)


@dataclass
class FrameResult:
    passes: FramePasses
    stats: dict
    selection: object
    selection_rows: list
    problems: list = field(default_factory=list)


def _timer():
    return time.perf_counter()


def _ms(start):
    return (time.perf_counter() - start) * 1000.0


class LayerPixels:
    """The covered pixels of one read-back G-buffer layer; per-pixel terms are computed only
    for the subsets that get rays."""

    def __init__(self, layer, origin, camera, materials: shading.MaterialTable):
        self.layer = layer
        self.flat = np.flatnonzero(layer.covered.ravel())
        self.position = layer.position.reshape(-1, 3)[self.flat]  # float32, camera-relative
        self.origin = np.asarray(origin, np.float64)
        self.element = layer.element.ravel()[self.flat]
        self.material = np.clip(layer.material.ravel()[self.flat], 0, len(materials.ior) - 1)
        self.roughness = layer.roughness.ravel()[self.flat]
        self._normal = layer.normal.reshape(-1, 3)[self.flat]
        self.camera = camera
        self.materials = materials

    def __len__(self):
        return len(self.flat)

    def world(self, index=slice(None)) -> np.ndarray:
        return self.position[index].astype(np.float64) + self.origin

    def view_directions(self, index=slice(None)) -> np.ndarray:
        """Unit directions from the camera (perspective) or the camera axis (orthographic)."""
        position = self.position[index]
        if self.camera.ortho:
            return np.broadcast_to(self.camera.forward.astype(np.float32), position.shape).copy()
        return shading.normalize(position)

    def normals(self, index=slice(None), view_directions=None) -> np.ndarray:
        """Unit shading normals facing the viewer (flipped where interpolation turned them away)."""
        normal = shading.normalize(self._normal[index])
        if view_directions is None:
            view_directions = self.view_directions(index)
        back = shading.dot(normal, view_directions) > 0
        normal[back] *= -1.0
        return normal

    def geometric_normals(self, index, view_directions) -> np.ndarray:
        """Face normals facing the camera (where secondary rays leave from: rules of tracer.py)."""
        return geometric_normals(self.layer, self.flat[index], view_directions)

    def camera_distance(self, index=slice(None)) -> np.ndarray:
        """Distance from the camera: the size of the points' float32 error, which secondary-ray
        offsets must exceed (telephoto views)."""
        position = self.position[index]
        return np.sqrt(shading.dot(position, position))


class FrameRenderer:
    """Renders the frames of one replay, carrying state from frame to frame."""

    def __init__(self, threads: int | None = None):
        self.threads = threads
        self.cost_model = None
        self.previous_selection = {}
        self.trace_scene = None
        self.frames_rendered = 0
        self.element_bounds = ElementBounds()
        # The error-aware relevance's per-element estimates (phrt_addon/benefit.py).
        self.benefit_model = benefit.BenefitModel()
        # Names to trace instead of the heuristic's choice (the oracle, outside timed runs), or None.
        self.forced_selection = None
        self.problems = ProblemLog()  # what this replay's snapshots skipped or approximated (engine/final.py)
        self._textures = {}  # id(snapshot texture) -> (texture, rules.prepare_texture of it)

    def close(self):
        if self.trace_scene is not None:
            self.trace_scene.close()
            self.trace_scene = None

    # ------------------------------------------------------------------
    def render(self, snapshot: SceneSnapshot, raster: RasterFrame) -> FrameResult:
        settings = snapshot.settings
        mode = settings.mode.upper()
        materials = shading.MaterialTable(snapshot.materials)
        if self.cost_model is None:
            self.cost_model = CostModel()
        n_elements = len(snapshot.elements)
        candidate = np.array([e.is_candidate for e in snapshot.elements], bool)

        # -- element statistics; the layers are read back only if rays may be traced ----
        start = _timer()
        front = raster.front_element
        area_px, centre_ndc, distance = element_pixel_stats(front, n_elements, raster.view_depth)
        select_ms = _ms(start)
        layers = None
        readback_ms = 0.0
        may_trace = mode != "RASTER" and bool(np.any(candidate & (area_px > 0)))
        if may_trace:
            start = _timer()
            gbuffer = raster.gbuffer()
            layers = {"opaque": LayerPixels(gbuffer.opaque, gbuffer.origin, snapshot.camera, materials),
                      "transparent": LayerPixels(gbuffer.transparent, gbuffer.origin, snapshot.camera, materials)}
            readback_ms = _ms(start)
        raster_ms = raster.raster_ms + readback_ms

        # -- selection --------------------------------------------------------
        start = _timer()
        shadow_lights = [light for light in snapshot.lights if light.cast_shadows]
        element_bounds = self.element_bounds(snapshot)
        footprint = self._shadow_footprints(layers, snapshot, element_bounds, area_px) \
            if shadow_lights and layers is not None else np.zeros(n_elements)
        learn_benefit = mode == "HYBRID" and str(settings.relevance).upper() == "ERROR"
        flags = {effect: np.array([getattr(e, effect) for e in snapshot.elements], bool)
                 for effect in ("shadows", "reflections", "refractions")}
        expected_benefit = self.benefit_model.benefit(
            [e.name for e in snapshot.elements],
            benefit.prior_per_pixel(layers, n_elements, flags["reflections"], flags["refractions"],
                                    flags["shadows"], materials)) if learn_benefit else None
        frame_elements = heuristic.FrameElements(
            names=[e.name for e in snapshot.elements],
            candidate=candidate,
            area_px=area_px, centre_ndc=centre_ndc, distance=distance,
            priority=np.array([e.priority for e in snapshot.elements], float),
            rt_cost=np.array([e.rt_cost for e in snapshot.elements], float),
            shadows=flags["shadows"], reflections=flags["reflections"], refractions=flags["refractions"],
            rays_per_pixel=_rays_per_pixel(snapshot, area_px, footprint),
            frame_px=raster.width * raster.height,
            near_clip=snapshot.camera.clip_start,
            benefit=expected_benefit,
        )
        selection = heuristic.select(
            frame_elements, self.previous_selection,
            heuristic.SelectionSettings(budget_ms=settings.budget_ms, selection_weight=settings.selection_weight,
                                        max_area_fraction=settings.max_area_fraction, mode=mode,
                                        cost_mode=settings.cost_mode, relevance=settings.relevance,
                                        order=settings.selection_order, budget_at=settings.budget_at),
            self.cost_model, frame=snapshot.frame)
        if self.forced_selection is not None:
            selection = heuristic.force_selection(selection, self.forced_selection)
        selected = np.asarray(selection.selected, bool)
        select_ms += _ms(start)

        # -- ray tracing ------------------------------------------------------
        start = _timer()
        counters = _Counters()
        element_rays = np.zeros(n_elements)
        traced = None
        if np.any(selected) and layers is not None:
            traced = self._trace(snapshot, layers, materials, selected, element_bounds, counters, element_rays)
        trace_ms = _ms(start)

        # -- lighting and composite (GPU) -----------------------------------------
        start = _timer()
        measure = learn_benefit and traced is not None
        combined = raster.shade(traced, measure_change=measure)
        composite_ms = _ms(start)
        # Uploading the traced results is part of the tracing's cost, which scales with the selection.
        traced_upload_ms = float(raster.stats.get("traced_upload_ms", 0.0)) if traced is not None else 0.0
        trace_ms += traced_upload_ms
        composite_ms = max(composite_ms - traced_upload_ms, 0.0)
        passes = self._passes(snapshot, raster, combined, selected, candidate)

        if measure:
            # The error-aware relevance learns what tracing changed, measured on the GPU beside the
            # image (selection bookkeeping: select_ms).
            start = _timer()
            difference = benefit.measure_differences(snapshot, layers, raster.traced_change(), traced, selected,
                                                     element_bounds)
            self.benefit_model.observe(frame_elements.names, selected, difference, area_px)
            select_ms += _ms(start)

        total_ms = raster_ms + select_ms + trace_ms + composite_ms
        setup_ms = raster.setup_ms + counters.upload_ms
        # One-time work (Embree builds, shader compiles, uploads, new shadow maps) is not a per-frame cost.
        self.cost_model.observe(FrameStats(
            raster_ms=max(raster_ms - raster.setup_ms, 0.0), select_ms=select_ms, composite_ms=composite_ms,
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
            "budget_ms": selection.budget_ms, "predicted_trace_ms": float(selection.predicted_trace_ms),
            "n_candidates": int(np.sum(frame_elements.candidate)),
            "n_visible": int(np.sum(np.asarray(selection.visible, bool))),
            "n_selected": int(np.sum(selected)), "rays": counters.rays,
            "shadow_rays": counters.shadow_rays, "reflection_rays": counters.reflection_rays,
            "refraction_rays": counters.refraction_rays, "upload_ms": counters.upload_ms,
            "setup_ms": setup_ms, "readback_ms": readback_ms,
            "gbuffer_ms": float(raster.stats.get("gbuffer_ms", raster.raster_ms)),
            "lighting_ms": composite_ms,
            "time_left_ms": float(selection.time_left_ms), "triangles": snapshot.n_triangles,
        }
        return FrameResult(passes=passes, stats=stats, selection=selection,
                           selection_rows=selection.rows(snapshot.frame), problems=list(snapshot.problems))

    # ------------------------------------------------------------------
    @staticmethod
    def _passes(snapshot, raster, combined, selected, candidate) -> FramePasses:
        front = np.asarray(raster.front_element)
        n = len(snapshot.elements)
        # Ids beyond the element list (a corrupt read-back) are no element.
        front = np.where((front >= 0) & (front < n), front, -1)
        candidate_flags = np.r_[candidate, False]
        selected_flags = np.r_[np.asarray(selected, bool), False]
        depth = np.where(np.isfinite(raster.view_depth), raster.view_depth, 1e10).astype(np.float32)
        if combined is not None:  # None: the image stayed on the GPU (the viewport draws it there)
            combined = np.ascontiguousarray(combined, dtype=np.float32)
            combined[..., :3] = shading.finite(combined[..., :3])
            combined[..., 3] = 1.0
        return FramePasses(
            combined=combined,
            depth=depth,
            normal=np.nan_to_num(raster.front_normal).astype(np.float32),
            selected=selected_flags[front].astype(np.float32),
            candidate=candidate_flags[front].astype(np.float32),
            element=(front + 1).astype(np.float32),
        )

    def _shadow_footprints(self, layers, snapshot, element_bounds, area_px):
        """Estimated shadow-ray count per element (pixels it can shadow, summed over lights),
        from a 1/FOOTPRINT_STEP^2 sub-sample of the opaque layer."""
        n = len(snapshot.elements)
        footprint = np.zeros(n)
        samples = layers["opaque"]
        if len(samples) == 0:
            return footprint
        points = samples.world(slice(None, None, FOOTPRINT_STEP * FOOTPRINT_STEP))
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
    def _prepared_texture(self, texture):
        """``rules.prepare_texture`` of a snapshot's texture, once per image (bounded)."""
        entry = self._textures.get(id(texture))
        if entry is None or entry[0] is not texture:
            if len(self._textures) >= 64:
                self._textures.clear()
            entry = self._textures[id(texture)] = (texture, rules.prepare_texture(texture))
        return entry[1]

    def _trace(self, snapshot, layers, materials, selected, element_bounds, counters, element_rays) -> TracedTerms:
        from .tracer import RadianceTracer, TraceScene, leave_surface, reflection_blend

        if self.trace_scene is None:
            self.trace_scene = TraceScene(self.threads)
        static_builds = self.trace_scene.stats["static_builds"]
        update_ms = self.trace_scene.update(snapshot, materials.casts_shadow[:len(snapshot.materials)])
        # Only a build of the static scene is one-time work; checking that nothing changed and
        # rebuilding the moving objects' scene recur every frame (the cost model learns them).
        if self.trace_scene.stats["static_builds"] != static_builds:
            counters.upload_ms = update_ms
        scene = self.trace_scene
        textures = {index: self._prepared_texture(m.texture) for index, m in enumerate(snapshot.materials)
                    if m.texture is not None}
        tracer = RadianceTracer(scene, snapshot, materials, textures)
        elements = snapshot.elements
        traced = TracedTerms()
        world = np.asarray(snapshot.world_color, dtype=np.float64)
        n_elements = len(elements)

        def ray_start(pixels, idx, view_dirs):
            """Trace-frame points, their geometric normals facing the camera and ray offsets."""
            points_trace = scene.to_trace(pixels.world(idx))  # only the pixels that get rays
            normal = pixels.geometric_normals(idx, view_dirs)
            eps = scene.epsilon(points_trace, pixels.camera_distance(idx), element=pixels.element[idx])
            return points_trace, normal, eps

        # Shadows: for each light, the pixels a selected caster can shadow get traced visibility.
        start = _timer()
        casters = [i for i in np.flatnonzero(selected) if elements[i].shadows and element_bounds[i] is not None]
        for layer_name, pixels in layers.items():
            if not casters or len(pixels) == 0:
                continue
            points_world = None
            for light_index, light in enumerate(snapshot.lights):
                if not light.cast_shadows:
                    continue
                if points_world is None:
                    points_world = pixels.world()
                index = ShadowRegionIndex(light, points_world)
                region = np.zeros(len(pixels), bool)
                for caster in casters:
                    caster_region = index.region(element_bounds[caster])
                    element_rays[caster] += np.count_nonzero(caster_region)
                    region |= caster_region
                idx = np.flatnonzero(region)
                if len(idx) == 0:
                    continue
                direction, _, _ = shading.light_incidence(light, scene.to_trace(points_world[idx]), scene.origin)
                view_dirs = pixels.view_directions(idx)
                facing = shading.dot(pixels.normals(idx, view_dirs), direction) > 0  # the BRDF is zero elsewhere
                idx, direction, view_dirs = idx[facing], direction[facing], view_dirs[facing]
                if len(idx) == 0:
                    continue
                points_trace, normal, eps = ray_start(pixels, idx, view_dirs)
                _, distance, _ = shading.light_incidence(light, points_trace, scene.origin)
                blocked = scene.occluded(points_trace + normal * eps[:, None], direction, distance - 2 * eps)
                traced.shadow_visibility[(layer_name, light_index)] = (
                    pixels.flat[idx], np.where(blocked, 0.0, 1.0).astype(np.float32))
                counters.shadow_rays += len(idx)
        counters.shadow_ms = _ms(start)
        # Reflections and refractions are bounces: none with max_bounces 0 (the raster result stays).
        bounces = int(snapshot.settings.max_bounces) >= 1

        # Reflections on selected elements' pixels (mirror direction, blended by roughness).
        start = _timer()
        rays_before = tracer.rays + tracer.shadow_rays
        reflecting = np.array([bool(selected[i]) and elements[i].reflections for i in range(n_elements)] + [False])
        for layer_name, pixels in layers.items():
            if not bounces or len(pixels) == 0:
                continue
            element_of = np.where((pixels.element >= 0) & (pixels.element < n_elements), pixels.element, -1)
            wanted = reflecting[element_of] & (reflection_blend(pixels.roughness) > 0)
            idx = np.flatnonzero(wanted)
            if len(idx) == 0:
                continue
            view_dirs = pixels.view_directions(idx)
            points_trace, normal, eps = ray_start(pixels, idx, view_dirs)
            direction = leave_surface(shading.reflect(view_dirs, pixels.normals(idx, view_dirs)), normal)
            radiance = tracer.radiance(points_trace + normal * eps[:, None], direction, 1)
            blend = reflection_blend(pixels.roughness[idx])[:, None]
            traced.reflection[layer_name] = (pixels.flat[idx], blend * radiance + (1.0 - blend) * world)
            np.add.at(element_rays, element_of[idx], 1)
        counters.reflection_rays = tracer.rays + tracer.shadow_rays - rays_before
        counters.reflection_ms = _ms(start)

        # Refractions through selected transparent elements (transparent layer only).
        start = _timer()
        rays_before = tracer.rays + tracer.shadow_rays
        pixels = layers["transparent"]
        if bounces and len(pixels):
            refracting = np.array([bool(selected[i]) and elements[i].refractions
                                   for i in range(n_elements)] + [False])
            element_of = np.where((pixels.element >= 0) & (pixels.element < n_elements), pixels.element, -1)
            wanted = refracting[element_of] & (materials.transmissive[pixels.material] > rules.TRANSPARENT_EPSILON)
            idx = np.flatnonzero(wanted)
            if len(idx):
                view_dirs = pixels.view_directions(idx)
                points_trace, normal, eps = ray_start(pixels, idx, view_dirs)
                ior = materials.ior[pixels.material[idx]]
                direction, _ = shading.refract(view_dirs, pixels.normals(idx, view_dirs), 1.0 / ior)
                direction = leave_surface(direction, normal, side=-1.0)
                radiance = tracer.radiance(points_trace - normal * eps[:, None], direction, 1)
                traced.refraction = (pixels.flat[idx], radiance)
                np.add.at(element_rays, element_of[idx], 1)
        counters.refraction_rays = tracer.rays + tracer.shadow_rays - rays_before
        counters.refraction_ms = _ms(start)
        return traced


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


def _rays_per_pixel(snapshot, area_px, footprint):
    """Rays one pixel of each element costs with its effects (input of the measured cost model)."""
    rays = np.zeros(len(snapshot.elements))
    safe_area = np.maximum(area_px, 1)
    for index, element in enumerate(snapshot.elements):
        per_pixel = 0.0
        if element.shadows:
            per_pixel += footprint[index] / safe_area[index]
        if element.reflections:
            per_pixel += 1.0 + len(snapshot.lights)  # the reflection ray and its hit's shadow rays
        if element.refractions:
            per_pixel += 2.0 + len(snapshot.lights)  # in, out, and the hit's shadow rays
        rays[index] = per_pixel
    return rays
