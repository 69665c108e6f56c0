"""The trace stage of a frame: shadows, reflections and refractions of the selected elements.

``TraceStage`` lives for a replay (one per ``FrameRenderer``): it owns the Embree scenes
(``trace_scene.TraceScene``) and the prepared textures.  ``run()`` takes the read-back
G-buffer layers and the selection and returns a ``TraceResult``: the ``TracedTerms``
the lighting and composite use in place of the raster terms, the counters the cost
model learns from, and the rays cast for each element (the same rays as the counters,
split between elements: the cost model's per-element ray ratios and per-effect ms per ray
must share one unit, or its global residual has to absorb the difference, which depends on
what is selected).

- Shadows: for each light, the pixels a selected caster can shadow (``shadow_region``)
  get traced visibility in place of the shadow map.
- Reflections: one mirror ray per pixel of a selected reflecting element, blended
  towards the environment by roughness (``tracer.reflection_blend``).
- Refractions: the transparent layer's pixels of a selected refracting element.
Rays leave along the geometric normal (``LayerPixels.geometric_normals``).
``embreex`` is imported only here, on the first traced frame.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..scene import rules, shading
from ..frame_types import TracedTerms
from .shadow_region import PointChunks, TiledShadowRegions


# Pixels are grouped in square screen tiles for the shadow regions' culling (shadow_region.py).
TILE_PIXELS = 8


def _ms(start):
    return (time.perf_counter() - start) * 1000.0


def screen_tiles(pixels, size: int = TILE_PIXELS) -> np.ndarray:
    """The screen tile (``size`` x ``size`` pixels) of each of a layer's pixels."""
    width = pixels.layer.covered.shape[1]
    rows, cols = np.divmod(pixels.flat, width)
    return (rows // size) * (-(-width // size)) + cols // size


def _attribute(element_rays, elements, weights, rays):
    """Add ``rays`` to ``element_rays`` of ``elements`` in proportion to ``weights``."""
    total = float(np.sum(weights))
    if rays > 0 and total > 0:
        np.add.at(element_rays, np.asarray(elements, np.int64), rays * np.asarray(weights, np.float64) / total)


def _attribute_to_pixels(element_rays, pixel_element, rays):
    """Add ``rays`` (every ray a batch of bounce rays cast, their hits' shadow rays and further
    bounces included) to the elements of the batch's pixels, in proportion to their pixels."""
    elements, pixels = np.unique(pixel_element, return_counts=True)
    _attribute(element_rays, elements, pixels, rays)


EFFECTS = ("shadows", "reflections", "refractions")


def traced_effects(elements, selected, effects=None) -> dict[str, np.ndarray]:
    """Per effect, the elements whose effect is traced: selected, tagged for it, and (when
    ``effects`` names the effect) chosen for it."""
    selected = np.asarray(selected, bool)
    wanted = {}
    for effect in EFFECTS:
        tagged = np.fromiter((bool(getattr(element, effect)) for element in elements), bool, len(elements))
        chosen = selected & tagged
        if effects is not None and effect in effects:
            chosen &= np.asarray(effects[effect], bool)
        wanted[effect] = chosen
    return wanted


@dataclass
class TraceCounters:
    """Rays cast and ms spent per effect; ``upload_ms``: a static Embree build (one-time work)."""

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


@dataclass
class TraceResult:
    traced: TracedTerms
    counters: TraceCounters = field(default_factory=TraceCounters)
    # (n_elements,) rays cast for each element, in the units of the counters: every ray of an effect
    # (a bounce's hit shadow rays and further bounces included) goes to the elements whose pixels
    # cast it, shared in proportion where casters' shadow regions overlap; summed, the counters' rays.
    element_rays: np.ndarray = None
    # (n_elements, 3) the same rays split by effect (EFFECTS order): what each item cast.
    item_rays: np.ndarray = None


class TraceStage:
    """Owns what tracing keeps between frames of a replay."""

    TEXTURE_CACHE_LIMIT = 64

    def __init__(self, threads: int | None = None):
        self.threads = threads
        self.trace_scene = None
        self._textures = {}  # id(snapshot texture) -> (texture, rules.prepare_texture of it)

    def close(self):
        if self.trace_scene is not None:
            self.trace_scene.close()
            self.trace_scene = None

    def _prepared_texture(self, texture):
        """``rules.prepare_texture`` of a snapshot's texture, once per image (bounded)."""
        entry = self._textures.get(id(texture))
        if entry is None or entry[0] is not texture:
            if len(self._textures) >= self.TEXTURE_CACHE_LIMIT:
                self._textures.clear()
            entry = self._textures[id(texture)] = (texture, rules.prepare_texture(texture))
        return entry[1]

    def run(self, snapshot, layers, materials, selected, element_bounds, effects=None) -> TraceResult:
        """Trace the selected elements' effects from the read-back ``layers``.

        ``effects`` (optional): per effect name (``shadows``, ``reflections``, ``refractions``)
        a bool array over elements of those whose effect is traced, for selections of
        (element, effect) items; by default every tagged effect of a selected element."""
        from .embree_scene import TraceScene
        from .tracer import RadianceTracer, leave_surface, reflection_blend

        counters = TraceCounters()
        item_rays = np.zeros((len(snapshot.elements), len(EFFECTS)))
        wanted_effects = traced_effects(snapshot.elements, selected, effects)
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
        start = time.perf_counter()
        casters = [i for i in np.flatnonzero(wanted_effects["shadows"]) if element_bounds[i] is not None]
        for layer_name, pixels in layers.items():
            if not casters or len(pixels) == 0:
                continue
            points_world = None
            for light_index, light in enumerate(snapshot.lights):
                if not light.cast_shadows:
                    continue
                if points_world is None:
                    points_world = pixels.world()
                    chunks = PointChunks(points_world, keys=screen_tiles(pixels))  # shared by the layer's lights
                index = TiledShadowRegions(light, points_world, chunks)
                region = np.zeros(len(pixels), bool)
                caster_regions = []
                for caster in casters:
                    caster_region = index.region(element_bounds[caster])
                    caster_regions.append(caster_region)
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
                # A ray in overlapping casters' regions is shared between them.
                _attribute(item_rays[:, 0], casters, [np.count_nonzero(caster_region[idx]) for caster_region
                                                   in caster_regions], len(idx))
        counters.shadow_ms = _ms(start)
        # Reflections and refractions are bounces: none with max_bounces 0 (the raster result stays).
        bounces = int(snapshot.settings.max_bounces) >= 1

        # Reflections on selected elements' pixels (mirror direction, blended by roughness).
        start = time.perf_counter()
        rays_before = tracer.rays + tracer.shadow_rays
        reflecting = np.r_[wanted_effects["reflections"], False]
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
            layer_rays_before = tracer.rays + tracer.shadow_rays
            radiance = tracer.radiance(points_trace + normal * eps[:, None], direction, 1)
            blend = reflection_blend(pixels.roughness[idx])[:, None]
            traced.reflection[layer_name] = (pixels.flat[idx], blend * radiance + (1.0 - blend) * world)
            _attribute_to_pixels(item_rays[:, 1], element_of[idx], tracer.rays + tracer.shadow_rays - layer_rays_before)
        counters.reflection_rays = tracer.rays + tracer.shadow_rays - rays_before
        counters.reflection_ms = _ms(start)

        # Refractions through selected transparent elements (transparent layer only).
        start = time.perf_counter()
        rays_before = tracer.rays + tracer.shadow_rays
        pixels = layers["transparent"]
        if bounces and len(pixels):
            refracting = np.r_[wanted_effects["refractions"], False]
            element_of = np.where((pixels.element >= 0) & (pixels.element < n_elements), pixels.element, -1)
            wanted = refracting[element_of] & (materials.transmissive[pixels.material] > rules.TRANSPARENT_EPSILON)
            idx = np.flatnonzero(wanted)
            if len(idx):
                view_dirs = pixels.view_directions(idx)
                points_trace, normal, eps = ray_start(pixels, idx, view_dirs)
                ior = materials.ior[pixels.material[idx]]
                direction, _ = shading.refract(view_dirs, pixels.normals(idx, view_dirs), 1.0 / ior)
                direction = leave_surface(direction, normal, side=-1.0)
                layer_rays_before = tracer.rays + tracer.shadow_rays
                radiance = tracer.radiance(points_trace - normal * eps[:, None], direction, 1)
                traced.refraction = (pixels.flat[idx], radiance)
                _attribute_to_pixels(item_rays[:, 2], element_of[idx], tracer.rays + tracer.shadow_rays - layer_rays_before)
        counters.refraction_rays = tracer.rays + tracer.shadow_rays - rays_before
        counters.refraction_ms = _ms(start)
        return TraceResult(traced=traced, counters=counters, element_rays=item_rays.sum(axis=1), item_rays=item_rays)
