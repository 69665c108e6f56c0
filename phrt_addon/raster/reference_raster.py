"""Deferred lighting and composite in numpy: the reference for the GPU's GLSL passes.

``ReferenceRaster`` is a ``frame.RasterFrame`` built from a ``GBuffer`` (with albedo)
and numpy shadow maps.  It shades with the functions of ``shading.py`` and the
lookup of ``shadowmap.py`` - the equations the GLSL of ``engine/gpu/`` (each function names its twin here)
implements - so that:

- ``tests/integration/test_gpu_frame.py`` renders one G-buffer through both and
  checks they agree (the parity test of the GPU path);
- core tests run ``FrameRenderer`` on a hand-built G-buffer without Blender.

It is about 7x slower than the GPU passes on llvmpipe (docs/platform-notes.md); the engine
never uses it to render.
"""
from __future__ import annotations

import numpy as np

from ..scene import shading
from .gbuffer import GBuffer
from .shadowmap import shadow_visibility


class ReferenceRaster:
    def __init__(self, snapshot, gbuffer: GBuffer, shadow_maps: dict | None = None):
        if gbuffer.opaque.albedo is None:
            raise ValueError("the reference lighting needs the G-buffer's albedo and metallic")
        self.snapshot = snapshot
        self._gbuffer = gbuffer
        self.shadow_maps = shadow_maps or {}
        self.height, self.width = gbuffer.height, gbuffer.width
        self.raster_ms = 0.0
        self.setup_ms = 0.0
        self.stats = {}
        self.front_element = gbuffer.front_element()
        self.view_depth = gbuffer.view_depth
        self.front_normal = gbuffer.front_normal()
        self._change = None

    def gbuffer(self, rect=None) -> GBuffer:
        """Both layers; with ``rect`` (x, y, w, h) only the pixels inside it, the others cleared,
        as the GPU's read-back of a rectangle returns them."""
        if rect is None:
            return self._gbuffer
        whole = self._gbuffer
        return GBuffer(opaque=whole.opaque.cropped(rect), transparent=whole.transparent.cropped(rect),
                       origin=whole.origin, view_depth=whole.view_depth)

    def _surface(self, layer, materials):
        camera = self.snapshot.camera
        flat = np.flatnonzero(layer.covered.ravel())
        position = layer.position.reshape(-1, 3)[flat]
        if camera.ortho:
            view_dirs = np.broadcast_to(camera.forward.astype(np.float32), position.shape).copy()
        else:
            view_dirs = shading.normalize(position)
        material = np.clip(layer.material.ravel()[flat], 0, len(materials.ior) - 1)
        normal = shading.normalize(layer.normal.reshape(-1, 3)[flat])
        normal[shading.dot(normal, view_dirs) > 0] *= -1.0
        surface = shading.SurfaceSamples(
            position=position, normal=normal, view=-view_dirs,
            albedo=layer.albedo.reshape(-1, 3)[flat], metallic=layer.metallic.ravel()[flat],
            roughness=layer.roughness.ravel()[flat],
            transmission=materials.transmission[material].astype(np.float32),
            ior=materials.ior[material].astype(np.float32),
            emission=materials.emission[material].astype(np.float32))
        return flat, material, surface

    def traced_change(self) -> np.ndarray:
        return self._change

    def shade(self, traced=None, measure_change=False) -> np.ndarray:
        """Combined (h, w, 4) of the frame, lit and composited as the GPU frame's ``shade()``;
        ``measure_change``: also what the traced terms changed (``traced_change``).

        GLSL twin: engine/gpu/surface_glsl.py shade_layer (one layer's colour)
        GLSL twin: engine/gpu/lighting_glsl.py light_layer (one light's term at one layer)
        GLSL twin: engine/gpu/lighting_glsl.py main (a layer's lights, and the opaque composite)
        GLSL twin: engine/gpu/composite.py composite_pixel (the composite of both layers)
        GLSL twin: engine/gpu/composite.py main (with measure_change: the traced change)"""
        if measure_change:
            with_traced = self._shade(traced)
            without = self._shade(None)
            difference = np.abs(with_traced[..., :3] - without[..., :3]) @ np.array([0.2126, 0.7152, 0.0722])
            self._change = np.zeros_like(with_traced)
            self._change[..., 0] = np.minimum(difference, 1.0)  # shadows and surface terms together
        return self._shade(traced)

    def _shade(self, traced=None) -> np.ndarray:
        snapshot = self.snapshot
        gbuffer = self._gbuffer
        materials = shading.MaterialTable(snapshot.materials)
        world = np.asarray(snapshot.world_color, dtype=np.float64)
        n = self.width * self.height
        shaded = {}
        for layer_name, layer in (("opaque", gbuffer.opaque), ("transparent", gbuffer.transparent)):
            flat, material, surface = self._surface(layer, materials)
            color = surface.emission.astype(np.float64)
            for light_index, light in enumerate(snapshot.lights):
                if len(surface) == 0:
                    break
                direction, _, irradiance = shading.light_incidence(light, surface.position, gbuffer.origin)
                response = shading.brdf_cosine(surface, direction)
                visibility = np.ones(len(surface))
                if light.cast_shadows:
                    maps = self.shadow_maps.get(light_index)
                    lit = np.flatnonzero(np.any(response > 0, axis=1))
                    if maps and len(lit):
                        visibility[lit] = shadow_visibility(maps, surface.position[lit], surface.normal[lit],
                                                            origin=gbuffer.origin)
                    override = traced.shadow_visibility.get((layer_name, light_index)) if traced else None
                    if override is not None:
                        image = np.full(n, -1.0)
                        image[override[0]] = override[1]
                        replaced = image[flat]
                        visibility = np.where(replaced >= 0, replaced, visibility)
                color += response * irradiance * visibility[:, None]
            diffuse_ambient, fresnel = shading.ambient(surface, world)
            color += diffuse_ambient
            transmissive = surface.transmission * (1.0 - surface.metallic)
            reflected = np.broadcast_to(world, color.shape).copy()
            if traced is not None and layer_name in traced.reflection:
                image = np.zeros((n, 4))
                pixels, radiance = traced.reflection[layer_name]
                image[pixels, :3] = radiance
                image[pixels, 3] = 1.0
                mine = image[flat]
                reflected = np.where(mine[:, 3:] > 0.5, mine[:, :3], reflected)
            cos_v = np.clip(shading.dot(surface.normal, surface.view), 0.0, 1.0)
            fresnel_t = shading.fresnel_dielectric(cos_v, surface.ior)
            reflect_weight = fresnel * (1.0 - transmissive)[:, None] + (transmissive * fresnel_t)[:, None]
            color += reflect_weight * reflected
            shaded[layer_name] = (flat, material, surface, color, transmissive, fresnel_t)

        image = np.broadcast_to(world, (n, 3)).copy()
        flat, _, _, color, _, _ = shaded["opaque"]
        image[flat] = color
        flat, material, surface, color, transmissive, fresnel_t = shaded["transparent"]
        if len(flat):
            behind = image[flat].copy()  # raster: straight through, no bending
            refracted = behind  # the transmitted part, bent where traced
            if traced is not None and traced.refraction is not None:
                traced_image = np.zeros((n, 4))
                pixels, radiance = traced.refraction
                traced_image[pixels, :3] = radiance
                traced_image[pixels, 3] = 1.0
                mine = traced_image[flat]
                refracted = np.where(mine[:, 3:] > 0.5, mine[:, :3], behind)
            # The 1 - alpha part goes straight on (as the tracer's alpha pass-through does).
            transmitted = (transmissive * (1.0 - fresnel_t))[:, None] * surface.albedo * refracted
            alpha = materials.alpha[material][:, None]
            image[flat] = alpha * (color + transmitted) + (1.0 - alpha) * behind
        combined = np.ones((self.height, self.width, 4), np.float32)
        combined[..., :3] = shading.finite(image).reshape(self.height, self.width, 3)
        return combined
