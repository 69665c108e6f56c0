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
Rates (``rates.py``): an effect traced at half or quarter rate casts its rays only at the
pixels of that frame's pattern (a shadow pixel takes the highest rate of the casters whose
regions hold it); the other pixels are reconstructed from the layer's G-buffer (depth,
normal, element id), and those that cannot be keep the raster term.
Rays leave along the geometric normal (``LayerPixels.geometric_normals``).
``embreex`` is imported only through ``embree_scene.py``: by ``prepare``, on the replay's first frame
that may trace (a candidate in view, not RASTER), or else by its first traced frame.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..scene import rules, shading
from ..frame_types import TracedTerms, rows_of
from ..gather import take_rows
from .rates import element_rates, reconstruct, traced_subset
from .trace_result import EFFECTS, TraceCounters, TraceResult, traced_effects
from .reconstruction_guide import layer_guide
from .pixel_tiles import ImageTiles
from .shadow_region import PointChunks, TiledShadowRegions


# Pixels are grouped in square screen tiles for the shadow regions' culling (shadow_region.py).
TILE_PIXELS = 8


def _ms(start):
    return (time.perf_counter() - start) * 1000.0


def layer_tiles(pixels, size: int = TILE_PIXELS):
    """A layer's points in ``size`` x ``size`` screen tiles: straight from the image when they
    cover at least a quarter of it (no sort, no world positions: 2.3 ms against 5.7 for
    arcade's opaque layer at 320x240), else sorted by tile (a transparent layer's few pixels:
    0.2 ms against 1.1 for the whole image's tiles)."""
    height, width = pixels.layer.covered.shape
    if 4 * len(pixels) >= height * width:
        return ImageTiles(pixels.layer.position, pixels.flat, pixels.origin, size)
    rows, cols = np.divmod(pixels.flat, width)
    return PointChunks(pixels.world(), keys=(rows // size) * (-(-width // size)) + cols // size)


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


@dataclass
class _Bounce:
    """One part of a frame's batch of bounce rays: an effect's rays from one layer."""
    effect: str  # "reflections" or "refractions"
    layer_name: str
    pixels: object  # LayerPixels
    wanted_idx: np.ndarray  # the layer's pixels wanting the effect
    cast: np.ndarray  # of those, the ones cast this frame (rates)
    ray_element: np.ndarray  # the element of each cast ray's pixel
    pixel_rate: np.ndarray
    origins: np.ndarray
    directions: np.ndarray
    blend: np.ndarray | None  # reflections: the traced share of each ray's colour


def _union(index_arrays, size: int):
    """(the sorted union of ``index_arrays``, indices in 0..size-1; for each index its row in
    that union): by a mask, not a sort (a light's shadow pixels are tens of thousands)."""
    if len(index_arrays) == 1:  # one light: its pixels are already sorted and distinct
        union = np.asarray(index_arrays[0], np.intp)
        row_of = np.zeros(size, np.intp)
        row_of[union] = np.arange(len(union))
        return union, row_of
    member = np.zeros(size, bool)
    for index in index_arrays:
        member[index] = True
    return np.flatnonzero(member), np.cumsum(member, dtype=np.intp) - 1


def _rows(array, index):
    """``array``'s rows ``index`` (sorted, distinct): the array itself when they are all of them
    (one light: no copy)."""
    return array if len(index) == len(array) else take_rows(array, index)


def _joined(arrays):
    return arrays[0] if len(arrays) == 1 else np.concatenate(arrays)


def ray_start(scene, pixels, idx, view_dirs, points_trace=None):
    """Trace-frame points (given, or of the pixels ``idx``), their geometric normals facing the
    camera and ray offsets."""
    if points_trace is None:
        points_trace = scene.to_trace(pixels.world(idx))  # only the pixels that get rays
    normal = pixels.geometric_normals(idx, view_dirs)
    eps = scene.epsilon(points_trace, pixels.camera_distance(idx), element=pixels.element[idx])
    return points_trace, normal, eps


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

    def prepare(self, snapshot, casts_shadow) -> float:
        """Bring the Embree scenes in line with ``snapshot``: built before the first frame that
        traces (``FrameRenderer``), then checked by every traced frame.  Returns the ms of a
        static build (one-time work), 0 when there was none."""
        from .embree_scene import TraceScene
        if self.trace_scene is None:
            self.trace_scene = TraceScene(self.threads)
        builds = self.trace_scene.stats["static_builds"]
        spent = self.trace_scene.update(snapshot, casts_shadow)
        return spent if self.trace_scene.stats["static_builds"] != builds else 0.0

    @staticmethod
    def _trace_shadows(lit, layer_name, pixels, scene, traced, counters, item_rays, casters, filled):
        """Every light's shadow rays of one layer as one batch.  Only the pixels cast this frame
        are prepared (world position, view direction, normals, offsets), each once however many
        lights' regions hold it; at a reduced rate that work shrinks with the rays.  The others
        are reconstructed; one facing away from the light gets a value it never uses.  Per ray
        the same origin, direction and length as light by light: the same visibility (arcade's
        ten lights cost ten passes over mostly the same pixels and ten Embree calls)."""
        cast_pixels, row_of = _union([idx[cast] for _, _, idx, cast, _, _ in lit], len(pixels))
        points = scene.to_trace(pixels.world(cast_pixels))
        view_dirs = pixels.view_directions(cast_pixels)
        normals = pixels.normals(cast_pixels, view_dirs)
        rays = []  # per light: (light index, its pixels, cast, rates, caster regions, rays' pixels, rows, dirs, lengths)
        for light_index, light, idx, cast, pixel_rate, caster_regions in lit:
            rows = row_of[idx[cast]]
            direction, distance, _ = shading.light_incidence(light, _rows(points, rows), scene.origin)
            facing = shading.dot(_rows(normals, rows), direction) > 0  # the BRDF is zero elsewhere
            keep = ~cast
            keep[np.flatnonzero(cast)[facing]] = True
            if not np.any(keep):
                continue
            rays.append((light_index, idx[keep], cast[keep], pixel_rate[keep], caster_regions,
                         idx[cast][facing], rows[facing], rows_of(direction, facing), np.compress(facing, distance)))
        if not rays:
            return
        # The offsets of the pixels some light's ray leaves from, each pixel's once.
        leaving, at_leaving = _union([ray[6] for ray in rays], len(cast_pixels))
        origins, normal, eps = ray_start(scene, pixels, cast_pixels[leaving], _rows(view_dirs, leaving),
                                         _rows(points, leaving))
        at = [at_leaving[ray[6]] for ray in rays]
        starts = _joined([_rows(origins, a) + _rows(normal, a) * _rows(eps, a)[:, None] for a in at])
        lengths = _joined([ray[8] - 2 * _rows(eps, a) for ray, a in zip(rays, at)])
        blocked = scene.occluded(starts, _joined([ray[7] for ray in rays]), lengths)
        offset = 0
        for light_index, idx, cast, pixel_rate, caster_regions, ray_idx, *_ in rays:
            visible = np.where(blocked[offset:offset + len(ray_idx)], 0.0, 1.0).astype(np.float32)
            offset += len(ray_idx)
            traced.shadow_visibility[(layer_name, light_index)] = filled(
                "shadows", layer_name, pixels, idx, cast, visible, pixel_rate)
            traced.shadow_owners[(layer_name, light_index)] = (pixels.flat[idx], idx, list(casters), caster_regions)
            counters.shadow_rays += len(ray_idx)
            # A ray in overlapping casters' regions is shared between them.
            _attribute(item_rays[:, 0], casters, [np.count_nonzero(caster_region[ray_idx]) for caster_region
                                               in caster_regions], len(ray_idx))

    def _prepared_texture(self, texture):
        """``rules.prepare_texture`` of a snapshot's texture, once per image (bounded)."""
        entry = self._textures.get(id(texture))
        if entry is None or entry[0] is not texture:
            if len(self._textures) >= self.TEXTURE_CACHE_LIMIT:
                self._textures.clear()
            entry = self._textures[id(texture)] = (texture, rules.prepare_texture(texture))
        return entry[1]

    @staticmethod
    def _trace_bounces(parts, tracer, scene, traced, filled, item_rays, counters, prepare_ms, world):
        """Trace every ``_Bounce`` part in one ``radiance`` call; fill ``traced`` and the
        reflection and refraction counters (the call's time and Embree time shared by rays)."""
        if not parts:  # no bounce this frame: no call at all (a call with no rays cost 1.9 ms)
            counters.reflection_ms, counters.refraction_ms = prepare_ms["reflections"], prepare_ms["refractions"]
            return
        start = time.perf_counter()
        embree_before = scene.stats["embree_ms"]
        tracer.batch_rays = np.zeros(len(parts))
        radiance = tracer.radiance(
            np.concatenate([part.origins for part in parts]) if parts else np.zeros((0, 3)),
            np.concatenate([part.directions for part in parts]) if parts else np.zeros((0, 3)), 1,
            batch=np.concatenate([np.full(len(part.origins), k) for k, part in enumerate(parts)]) if parts
            else np.zeros(0, np.int64))
        bounce_ms, bounce_embree_ms = _ms(start), scene.stats["embree_ms"] - embree_before
        rays = tracer.batch_rays[:len(parts)]
        # Each effect's share of the batch: its rays (or, with none cast at all, its parts).
        weight = rays if rays.sum() > 0 else np.ones(len(parts))
        ms = dict(prepare_ms)
        effect_rays = {"reflections": 0, "refractions": 0}
        effect_share = {"reflections": 0.0, "refractions": 0.0}
        first = 0
        for k, part in enumerate(parts):
            begin = time.perf_counter()
            colour = radiance[first:first + len(part.origins)]
            first += len(part.origins)
            if part.effect == "reflections":
                traced.reflection[part.layer_name] = filled(
                    "reflections", part.layer_name, part.pixels, part.wanted_idx, part.cast,
                    part.blend * colour + (1.0 - part.blend) * world, part.pixel_rate)
            else:
                traced.refraction = filled("refractions", part.layer_name, part.pixels, part.wanted_idx, part.cast,
                                           colour, part.pixel_rate)
            column = EFFECTS.index(part.effect)
            _attribute_to_pixels(item_rays[:, column], part.ray_element, float(rays[k]))
            effect_rays[part.effect] += int(rays[k])
            effect_share[part.effect] += float(weight[k] / weight.sum())
            ms[part.effect] += _ms(begin)
        counters.reflection_rays, counters.refraction_rays = effect_rays["reflections"], effect_rays["refractions"]
        counters.reflection_ms = ms["reflections"] + bounce_ms * effect_share["reflections"]
        counters.refraction_ms = ms["refractions"] + bounce_ms * effect_share["refractions"]
        counters.reflection_embree_ms = bounce_embree_ms * effect_share["reflections"]
        counters.refraction_embree_ms = bounce_embree_ms * effect_share["refractions"]

    def run(self, snapshot, layers, materials, selected, element_bounds, effects=None, rates=None) -> TraceResult:
        """Trace the selected elements' effects from the read-back ``layers``.

        ``effects`` (optional): per effect name (``shadows``, ``reflections``, ``refractions``)
        a bool array over elements of those whose effect is traced, for selections of
        (element, effect) items; by default every tagged effect of a selected element.
        ``rates`` (optional): per effect name a float array over elements of the rate each
        element's effect is traced at (one of ``rates.RATES``; 1.0 where not given)."""
        from .tracer import RadianceTracer, leave_surface, reflection_blend

        counters = TraceCounters()
        item_rays = np.zeros((len(snapshot.elements), len(EFFECTS)))
        wanted_effects = traced_effects(snapshot.elements, selected, effects)
        # Only a build of the static scene is one-time work; checking that nothing changed and
        # rebuilding the moving objects' scene recur every frame (the cost model learns them).
        counters.upload_ms = self.prepare(snapshot, materials.casts_shadow[:len(snapshot.materials)])
        scene = self.trace_scene
        textures = {index: self._prepared_texture(m.texture) for index, m in enumerate(snapshot.materials)
                    if m.texture is not None}
        tracer = RadianceTracer(scene, snapshot, materials, textures)
        elements = snapshot.elements
        traced = TracedTerms()
        world = np.asarray(snapshot.world_color, dtype=np.float64)
        n_elements = len(elements)
        rate_of = {effect: element_rates(rates, effect, n_elements) for effect in EFFECTS}
        height, width = next(iter(layers.values())).layer.covered.shape
        effect_rate = {effect: np.zeros(height * width, np.float32) for effect in EFFECTS}
        guides = {}

        def rated(pixels, idx, pixel_rate):
            """Of the layer's pixels ``idx`` wanting an effect at ``pixel_rate``, those cast this frame."""
            if np.all(pixel_rate == 1.0):
                return np.ones(len(idx), bool)
            return traced_subset(pixels.flat[idx], pixel_rate, height, width, snapshot.frame)

        def filled(effect, layer_name, pixels, idx, cast, values, pixel_rate):
            """(flat pixels, values) of ``effect`` at every pixel of ``idx`` that has one: the
            traced ``values`` at ``idx[cast]``, the others reconstructed."""
            flat = pixels.flat[idx]
            if not np.all(cast):
                if layer_name not in guides:  # once a layer and frame: not a per-pixel cost
                    guides[layer_name] = layer_guide(pixels.layer)
                begin = time.perf_counter()
                out = reconstruct(flat, flat[cast], values, guides[layer_name], width, pixel_rate)
                counters.reconstruct_ms[effect] = counters.reconstruct_ms.get(effect, 0.0) + _ms(begin)
                counters.reconstructed_px[effect] = counters.reconstructed_px.get(effect, 0) + int(np.count_nonzero(~cast))
                pixel_rate = pixel_rate[np.searchsorted(flat, out.flat)]
                flat, values = out.flat, out.values.astype(values.dtype)
            np.maximum.at(effect_rate[effect], flat, np.broadcast_to(pixel_rate, flat.shape).astype(np.float32))
            return flat, values

        # Shadows: for each light, the pixels a selected caster can shadow get traced visibility.
        start = time.perf_counter()
        embree_before = scene.stats["embree_ms"]
        casters = [i for i in np.flatnonzero(wanted_effects["shadows"]) if element_bounds[i] is not None]
        for layer_name, pixels in layers.items():
            if not casters or len(pixels) == 0:
                continue
            chunks = None
            lit = []  # per light: (light index, light, its pixels, cast this frame, their rates, caster regions)
            for light_index, light in enumerate(snapshot.lights):
                if not light.cast_shadows:
                    continue
                setup_start = time.perf_counter()
                if chunks is None:  # the layer's points in screen tiles, shared by its lights
                    chunks = layer_tiles(pixels)
                # World positions only of the points in tiles a caster may reach (pixels.world(idx)).
                index = TiledShadowRegions(light, pixels.world, chunks)
                caster_regions = index.regions([element_bounds[caster] for caster in casters])
                region = np.logical_or.reduce(caster_regions)
                counters.shadow_setup_ms += _ms(setup_start)
                idx = np.flatnonzero(region)
                if len(idx) == 0:
                    continue
                # A pixel in several casters' regions is traced at the highest of their rates.
                pixel_rate = np.zeros(len(idx))
                for caster, caster_region in zip(casters, caster_regions):
                    pixel_rate = np.where(caster_region[idx], np.maximum(pixel_rate, rate_of["shadows"][caster]),
                                          pixel_rate)
                lit.append((light_index, light, idx, rated(pixels, idx, pixel_rate), pixel_rate, caster_regions))
            if lit:
                self._trace_shadows(lit, layer_name, pixels, scene, traced, counters, item_rays, casters, filled)
        counters.shadow_ms = _ms(start)
        counters.shadow_embree_ms = scene.stats["embree_ms"] - embree_before
        # Reflections and refractions are bounces: none with max_bounces 0 (the raster result stays).
        bounces = int(snapshot.settings.max_bounces) >= 1

        # Reflections (on selected elements' pixels, the mirror direction blended by roughness)
        # and refractions (through selected transparent elements, transparent layer only) leave
        # as one batch of rays: a bounce level's numpy and Embree calls are paid once, not once
        # per layer and effect (a glass ball's reflection and refraction were two recursions
        # of 5-7 levels).  Each part keeps count of the rays its paths cast; the batch's time is
        # shared between the effects in proportion to them.
        parts = []
        prepare_ms = {"reflections": 0.0, "refractions": 0.0}
        start = time.perf_counter()
        reflecting = np.r_[wanted_effects["reflections"], False]
        for layer_name, pixels in layers.items():
            if not bounces or len(pixels) == 0 or not reflecting.any():
                continue
            element_of = np.where((pixels.element >= 0) & (pixels.element < n_elements), pixels.element, -1)
            wanted = reflecting[element_of] & (reflection_blend(pixels.roughness) > 0)
            wanted_idx = np.flatnonzero(wanted)
            if len(wanted_idx) == 0:
                continue
            pixel_rate = rate_of["reflections"][element_of[wanted_idx]]
            cast = rated(pixels, wanted_idx, pixel_rate)
            idx = wanted_idx[cast]
            view_dirs = pixels.view_directions(idx)
            points_trace, normal, eps = ray_start(scene, pixels, idx, view_dirs)
            direction = leave_surface(shading.reflect(view_dirs, pixels.normals(idx, view_dirs)), normal)
            parts.append(_Bounce("reflections", layer_name, pixels, wanted_idx, cast, element_of[idx], pixel_rate,
                                 points_trace + normal * eps[:, None], direction,
                                 reflection_blend(pixels.roughness[idx])[:, None]))
        prepare_ms["reflections"] = _ms(start)
        start = time.perf_counter()
        pixels = layers["transparent"]
        refracting = np.r_[wanted_effects["refractions"], False]
        if bounces and len(pixels) and refracting.any():
            element_of = np.where((pixels.element >= 0) & (pixels.element < n_elements), pixels.element, -1)
            wanted = refracting[element_of] & (materials.transmissive[pixels.material] > rules.TRANSPARENT_EPSILON)
            wanted_idx = np.flatnonzero(wanted)
            pixel_rate = rate_of["refractions"][element_of[wanted_idx]]
            cast = rated(pixels, wanted_idx, pixel_rate)
            idx = wanted_idx[cast]
            if len(idx):
                view_dirs = pixels.view_directions(idx)
                points_trace, normal, eps = ray_start(scene, pixels, idx, view_dirs)
                ior = materials.ior[pixels.material[idx]]
                direction, _ = shading.refract(view_dirs, pixels.normals(idx, view_dirs), 1.0 / ior)
                direction = leave_surface(direction, normal, side=-1.0)
                parts.append(_Bounce("refractions", "transparent", pixels, wanted_idx, cast, element_of[idx],
                                     pixel_rate, points_trace - normal * eps[:, None], direction, None))
        prepare_ms["refractions"] = _ms(start)
        self._trace_bounces(parts, tracer, scene, traced, filled, item_rays, counters, prepare_ms, world)
        effect_rate = {effect: image.reshape(height, width) for effect, image in effect_rate.items()}
        return TraceResult(traced=traced, counters=counters, element_rays=item_rays.sum(axis=1), item_rays=item_rays,
                           rate=np.maximum.reduce(list(effect_rate.values())), effect_rate=effect_rate)
