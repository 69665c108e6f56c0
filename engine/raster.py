"""The raster half of a frame on the GPU: G-buffer, shadow maps, deferred lighting, composite.

Runs inside ``RenderEngine.render()`` (``bl_use_gpu_context = True`` gives a GPU
context, even in background mode, where llvmpipe serves it on the CPU) or
``view_draw()``.  ``GPUFrame`` implements the core's ``RasterFrame`` protocol
(``phrt_addon/frame.py``):

1. ``draw()``: the opaque layer, then the nearest transparent surfaces in front of
   it, into textures kept by ``engine/gpu_resources.py``; a resolve pass writes the
   front element id and the front normal and depth, which are read back (the
   selection's A, P, D and the Normal and Depth passes).  Shadow maps are rendered
   only when their light or the geometry changed and stay on the GPU.
2. ``gbuffer()``: the full layers read back, only when rays will be traced.
3. ``shade(traced)``: full-screen lighting passes of up to ``shaders.LIGHTS_PER_PASS``
   lights per layer (shadow-map lookup, or the traced visibility where the tracer
   replaced it; the transparent layer's passes only under its mask), then the
   composite (ambient, reflections, transparency, traced reflections and
   refractions), and one read-back of the final image.

Read-back follows docs/platform-notes.md: a flat ``gpu.types.Buffer`` and a reshape.
"""
from __future__ import annotations

import hashlib
import time

import numpy as np

from ..phrt_addon.raster import draw_chunks
from ..phrt_addon.scene import rules, shading
from ..phrt_addon.raster.gbuffer import GBuffer, GBufferLayer
from ..phrt_addon.scene.snapshot import SceneSnapshot
from ..phrt_addon.raster.shadowmap import ShadowMap, light_views
from . import shaders
from . import session
from .gpu_resources import GPUResources, ShadowAtlas, gpu_module

# Material indices are stored +1 in the float position target's w: exact to 2^24.
MAX_MATERIALS = (1 << 24) - 1


# shaders.LIGHT_STRUCT: 6 view-projections, 6 axes, 6 vec4s.
LIGHT_UBO_FLOATS = 6 * 16 + 6 * 4 + 6 * 4


def _matrix_list(matrix) -> list:
    """Row-major 4x4 -> the column-major flat list GLSL expects."""
    return np.asarray(matrix, dtype=np.float32).T.ravel().tolist()


def _ms(start):
    return (time.perf_counter() - start) * 1000.0


def _model_relative(matrix_world, origin):
    model = np.array(matrix_world, dtype=np.float64)
    model[:3, 3] -= origin
    return model


def _ubo(gpu, values):
    values = np.ascontiguousarray(values, dtype=np.float32).ravel()
    return gpu.types.GPUUniformBuf(gpu.types.Buffer("FLOAT", values.size, values))


def shadow_scene_key(snapshot) -> bytes:
    """What every shadow map of a frame sees: which materials cast shadows (rules.casts_shadow)
    and every mesh's content and placement (computed once per frame, not per light)."""
    digest = hashlib.blake2b(digest_size=16)
    materials = snapshot.materials
    if materials:
        casts = rules.casts_shadow_values(np.array([m.transmission for m in materials], np.float64),
                                          np.array([m.metallic for m in materials], np.float64),
                                          np.array([m.alpha for m in materials], np.float64))
        digest.update(np.asarray(casts, np.uint8).tobytes())
    for mesh in snapshot.meshes:
        digest.update(mesh.geometry_key.encode())
        digest.update(np.asarray(mesh.matrix_world, np.float64).tobytes())
    return digest.digest()


def shadow_key(light, scene_key: bytes, size) -> str:
    """Identifies a light's shadow maps: the light's own parameters and what the maps see
    (``shadow_scene_key``)."""
    digest = hashlib.blake2b(scene_key, digest_size=16)
    digest.update(repr((light.kind, tuple(light.position), tuple(light.direction), light.spot_size, size)).encode())
    return digest.hexdigest()


class GPUFrame:
    """The GPU work of one frame. ``draw()`` first; then the core calls ``gbuffer()`` if it
    traces and ``shade()`` once."""

    def __init__(self, snapshot: SceneSnapshot, resources: GPUResources | None = None):
        self.snapshot = snapshot
        self.resources = resources if resources is not None else session.current().resources
        self.width, self.height = snapshot.camera.width, snapshot.camera.height
        self.materials = shading.MaterialTable(snapshot.materials)
        self.raster_ms = 0.0
        self.setup_ms = 0.0
        self.stats = {}
        self._gbuffer = None
        self._transparent_drawn = False
        self.read_combined = True  # False: shade() leaves the image on the GPU (the viewport draws it)
        self._measure = False

    # -- protocol --------------------------------------------------------------
    def draw(self):
        """G-buffer, resolve and its read-back, shadow maps; sets raster_ms and setup_ms."""
        if len(self.snapshot.elements) > rules.MAX_ELEMENTS:
            raise ValueError(f"{len(self.snapshot.elements)} ray tracing elements: the G-buffer tells at most "
                             f"{rules.MAX_ELEMENTS} apart; tag fewer objects or materials")
        if len(self.snapshot.materials) > MAX_MATERIALS:
            raise ValueError(f"{len(self.snapshot.materials)} materials: the G-buffer tells at most "
                             f"{MAX_MATERIALS} apart")
        gpu = gpu_module()
        start = time.perf_counter()
        created_before = self.resources.uploads + sum(self.resources.created[kind] for kind in ("shader", "target"))
        setup_start = time.perf_counter()
        self._shaders = {name: self.resources.shader(name) for name in (
            "gbuffer", "gbuffer_untextured", "resolve", "composite", "composite_opaque", "shadow")}
        counts = self._light_counts()
        # All lights in one pass: that pass also composites the opaque layer (one full-screen
        # pass less), if the implementation has the sampler it needs.
        self._fused = len(counts) == 1 and (shaders.lighting_samplers(counts[0], with_composite=True)
                                            <= self.resources.max_fragment_samplers())
        self.targets = self.resources.targets(self.width, self.height)
        self.material_table = self.resources.material_table(self.materials)
        self._draw_list = []
        keys = set()
        for mesh in self.snapshot.meshes:
            if mesh.n_triangles == 0:
                continue
            keys.add(mesh.geometry_key)
            _, groups, boxes = self.resources.mesh_batches(mesh)
            self._draw_list.append((mesh, groups, boxes))
        self.resources.retain_meshes(keys)
        textures = {}
        for index, material in enumerate(self.snapshot.materials):
            texture = self.resources.material_texture(material)
            if texture is not None:
                textures[index] = texture
        self._material_textures = textures
        created_after = self.resources.uploads + sum(self.resources.created[kind] for kind in ("shader", "target"))
        setup_ms = _ms(setup_start) if created_after > created_before else 0.0
        setup_ms += self._ensure_shadow_maps(gpu)
        # The lighting variants need the shadow maps' kinds (cube or single view per light slot).
        created_before = self.resources.created["shader"]
        setup_start = time.perf_counter()
        self._lighting_names = self._lighting_shader_names()  # once per frame: shade() uses them
        for name in self._lighting_names:
            self._shaders[name] = self.resources.shader(name)
        if self.resources.created["shader"] > created_before:
            setup_ms += _ms(setup_start)
        self._draw_gbuffer(gpu)
        self.resources.frames_drawn += 1
        self._resolve(gpu)
        self.setup_ms = setup_ms
        self.raster_ms = _ms(start)
        self.stats["gbuffer_ms"] = self.raster_ms - setup_ms

    def gbuffer(self) -> GBuffer:
        """Both layers read back (float32 positions relative to the camera)."""
        if self._gbuffer is None:
            gpu = gpu_module()
            framebuffer = gpu.types.GPUFrameBuffer(color_slots=(
                self.targets["opaque_position"], self.targets["opaque_normal"], self.targets["opaque_element"],
                self.targets["transparent_position"], self.targets["transparent_normal"],
                self.targets["transparent_element"]))
            opaque = self._read_layer(gpu, framebuffer, 0)
            transparent = self._read_layer(gpu, framebuffer, 3) if self._transparent_drawn else \
                GBufferLayer.empty(self.width, self.height)
            self._gbuffer = GBuffer(opaque=opaque, transparent=transparent, origin=self.snapshot.camera.position,
                                    view_depth=self.view_depth)
        return self._gbuffer

    def traced_change(self) -> np.ndarray:
        """(h, w, 4) of the last ``shade(..., measure_change=True)``: x the luminance of what traced
        reflections and refractions changed, y what traced shadows changed (clipped to [0, 1])."""
        gpu = gpu_module()
        framebuffer = gpu.types.GPUFrameBuffer(color_slots=(self.targets["traced_change"],))
        return self._read(gpu, framebuffer, 0, "FLOAT", 4)

    def read_albedo(self):
        """(opaque, transparent) albedo + metallic, (h, w, 4): only the reference lighting needs them."""
        gpu = gpu_module()
        framebuffer = gpu.types.GPUFrameBuffer(color_slots=(self.targets["opaque_albedo"],
                                                            self.targets["transparent_albedo"]))
        result = []
        for slot in (0, 1):
            stored = self._read(gpu, framebuffer, slot, "FLOAT", 4)
            stored[..., :3] *= stored[..., :3]  # stored as sqrt
            result.append(stored)
        return tuple(result)

    def _light_slots(self) -> list:
        """Per lighting pass, (kind code, map code) of each light: map 0 none, 1 one view, 2
        cube map (what the pass's shader variant computes, shaders.lighting_name)."""
        per_pass, lights = shaders.LIGHTS_PER_PASS, self.snapshot.lights
        slots = []
        for index, light in enumerate(lights):
            if index % per_pass == 0:
                slots.append([])
            atlas = self.atlases.get(index) if light.cast_shadows else None
            shadow = 0 if atlas is None else (2 if len(atlas.views) == 6 else 1)
            slots[-1].append((shaders.LIGHT_KIND_CODES.get(light.kind, 1), shadow))
        return slots

    def _lighting_shader_names(self) -> list:
        """The lighting shader of each pass (shaders.lighting_name), and the opaque layer's
        variant that also composites when there is one pass (``_fused``)."""
        slots = self._light_slots()
        names = [shaders.lighting_name(per_pass) for per_pass in slots]
        if self._fused:
            names.append(shaders.lighting_name(slots[0], composite=True))
        return names

    def _light_counts(self) -> list:
        """Lights per lighting pass (LIGHTS_PER_PASS, the rest in the last)."""
        per_pass, lights = shaders.LIGHTS_PER_PASS, len(self.snapshot.lights)
        return [min(per_pass, lights - first) for first in range(0, lights, per_pass)]

    def shade(self, traced, measure_change: bool = False) -> np.ndarray | None:
        """Deferred lighting and composite with the tracer's results; returns Combined (h, w, 4),
        or None when ``read_combined`` is off (the frame target "combined" holds it).
        ``measure_change``: also write what the traced terms changed (``traced_change``)."""
        gpu = gpu_module()
        start = time.perf_counter()
        uploads = self._upload_traced(gpu, traced)
        self.stats["traced_upload_ms"] = _ms(start)
        self._measure = bool(measure_change)
        # A driver compiles a shader for each pipeline state on its first draw (llvmpipe JITs the
        # fragment code then): the first frame of a configuration pays it once, as set-up.
        configuration = (tuple(self._lighting_names), self._transparent_drawn, self._measure)
        first_use = self.resources.first_use("shade", configuration)
        self._traced_flags = (float("opaque" in uploads["reflection"]), float("transparent" in uploads["reflection"]),
                              float(uploads["refraction"] is not None))
        self._light(gpu, uploads)
        combined = self._composite(gpu, uploads)
        self.stats["lighting_ms"] = _ms(start)
        self.stats["shade_setup_ms"] = self.stats["lighting_ms"] - self.stats["traced_upload_ms"] if first_use else 0.0
        return combined

    # -- drawing -----------------------------------------------------------------
    def _camera_ubo(self, gpu, traced_flags=(0.0, 0.0, 0.0)):
        camera = self.snapshot.camera
        values = np.zeros(12, np.float32)
        values[:3] = camera.forward
        values[3] = 1.0 if camera.ortho else 0.0
        values[4:7] = np.asarray(self.snapshot.world_color, np.float64)[:3]
        values[8:11] = traced_flags
        return _ubo(gpu, values)

    def _view_proj(self):
        """Projection @ view with the camera at the origin: positions relative to the camera keep
        float32 precision at any world coordinate."""
        camera = self.snapshot.camera
        view_relative = camera.view_matrix.copy()
        view_relative[:3, 3] = (camera.view_matrix @ np.r_[camera.position, 1.0])[:3]
        return np.asarray(camera.projection, dtype=np.float64) @ view_relative

    def _draw_gbuffer(self, gpu):
        targets = self.targets
        origin = self.snapshot.camera.position
        view_proj = self._view_proj()
        ubo = _ubo(gpu, np.r_[np.asarray(_matrix_list(view_proj), np.float32), np.zeros(4, np.float32)])
        transparent = np.array([m.is_transparent for m in self.snapshot.materials], dtype=bool)
        textured = np.zeros(len(self.snapshot.materials), bool)
        textured[list(self._material_textures)] = True
        has_transparent = any(transparent[material] for _, groups, _ in self._draw_list for material, *_ in groups)
        # Chunks wholly outside the view are not drawn (draw_chunks): one test per mesh and frame.
        visible = []
        for mesh, _, boxes in self._draw_list:
            model = _model_relative(mesh.matrix_world, origin)
            visible.append((model, ~draw_chunks.boxes_outside(view_proj @ model, boxes)))
        drawn = culled = 0
        for layer in ("opaque", "transparent"):
            framebuffer = gpu.types.GPUFrameBuffer(
                depth_slot=targets["opaque_depth"],
                color_slots=tuple(targets[f"{layer}_{name}"] for name in ("position", "normal", "albedo", "element")))
            with framebuffer.bind():
                gpu.state.viewport_set(0, 0, self.width, self.height)
                if layer == "opaque":
                    framebuffer.clear(color=(0.0, 0.0, 0.0, 0.0), depth=1.0)
                else:
                    # Keep the opaque depth: only transparent surfaces in front of it pass.
                    framebuffer.clear(color=(0.0, 0.0, 0.0, 0.0))
                if layer == "opaque" or has_transparent:
                    gpu.state.depth_test_set("LESS_EQUAL")
                    gpu.state.depth_mask_set(True)
                    gpu.state.face_culling_set("NONE")
                    gpu.state.blend_set("NONE")
                    in_layer = ~transparent if layer == "opaque" else transparent
                    # Materials without an image first, with the variant that samples none.
                    for name, wanted in (("gbuffer_untextured", in_layer & ~textured),
                                         ("gbuffer", in_layer & textured)):
                        if not any(wanted[material] for _, groups, _ in self._draw_list
                                   for material, *_ in groups):
                            continue
                        shader = self._shaders[name]
                        shader.bind()
                        shader.uniform_block("frame", ubo)
                        counts = self._draw_groups(shader, visible, wanted)
                        drawn, culled = drawn + counts[0], culled + counts[1]
                    gpu.state.depth_test_set("NONE")
                    gpu.state.depth_mask_set(False)
        self.stats["chunks_drawn"], self.stats["chunks_culled"] = drawn, culled
        self._transparent_drawn = has_transparent

    def _draw_groups(self, shader, visible, wanted):
        """Draw the visible chunks of the groups whose material is ``wanted``; returns
        (chunks drawn, chunks culled)."""
        drawn = culled = 0
        for (mesh, groups, _), (model, keep) in zip(self._draw_list, visible):
            chunk = 0
            model_set = False
            for material_index, element_index, batches, _ in groups:
                first, chunk = chunk, chunk + len(batches)
                if not wanted[material_index]:
                    continue
                shown = [batch for batch, show in zip(batches, keep[first:chunk]) if show]
                drawn, culled = drawn + len(shown), culled + len(batches) - len(shown)
                if not shown:
                    continue
                if not model_set:
                    shader.uniform_float("model", _matrix_list(model))
                    model_set = True
                texture = self._material_textures.get(material_index)
                shader.uniform_float("base_color", (*self.materials.base_color[material_index], 1.0))
                shader.uniform_float("params", (float(self.materials.roughness[material_index]),
                                                float(self.materials.metallic[material_index]),
                                                1.0 if texture is not None else 0.0, 0.0))
                shader.uniform_int("ids", (int(material_index), int(element_index)))
                if texture is not None:
                    shader.uniform_sampler("base_tex", texture)
                for batch in shown:
                    batch.draw(shader)
        return drawn, culled

    def _fullscreen(self, gpu, name, framebuffer, bind, write_depth=False, depth_test="NONE"):
        """One full-screen pass; ``write_depth``: the shader's gl_FragDepth is kept; ``depth_test``:
        the pass (at depth 0.5) is drawn where it passes the attached depth."""
        shader = self._shaders[name]
        with framebuffer.bind():
            gpu.state.viewport_set(0, 0, self.width, self.height)
            # Depth is written only with the test on ("ALWAYS"); the shader sets gl_FragDepth.
            gpu.state.depth_test_set("ALWAYS" if write_depth else depth_test)
            gpu.state.depth_mask_set(write_depth)
            shader.bind()
            bind(shader)
            self.resources.fullscreen_batch(shader).draw(shader)
            gpu.state.depth_test_set("NONE")
            gpu.state.depth_mask_set(False)

    def _bind_layers(self, shader, albedo=True, element=False):
        for layer in ("opaque", "transparent"):
            names = ["position", "normal"] + (["albedo"] if albedo else []) + (["element"] if element else [])
            for name in names:
                shader.uniform_sampler(f"{layer}_{name}", self.targets[f"{layer}_{name}"])

    def _resolve(self, gpu):
        targets = self.targets
        # Also writes the transparent layer's mask (depth 0 where it covers the pixel) that the
        # lighting passes of that layer are depth-tested against.
        framebuffer = gpu.types.GPUFrameBuffer(depth_slot=targets["transparent_mask"],
                                               color_slots=(targets["normal_depth"], targets["front_element"]))
        camera_ubo = self._camera_ubo(gpu)

        def bind(shader):
            shader.uniform_block("camera", camera_ubo)
            self._bind_layers(shader, albedo=False, element=True)

        gpu.state.blend_set("NONE")
        self._fullscreen(gpu, "resolve", framebuffer, bind, write_depth=True)
        normal_depth = self._read(gpu, framebuffer, 0, "FLOAT", 4)
        element = self._read(gpu, framebuffer, 1, "UINT", 1)
        depth = normal_depth[..., 3]
        self.view_depth = np.where(depth < 1e9, depth, np.inf).astype(np.float32)
        self.front_normal = np.ascontiguousarray(normal_depth[..., :3])
        self.front_element = element.astype(np.int64) - 1

    # -- shadow maps ---------------------------------------------------------------
    def _ensure_shadow_maps(self, gpu) -> float:
        """Render the maps that are missing (new light, moved light, changed geometry);
        returns the ms spent (one-time work)."""
        self.atlases = {}
        snapshot = self.snapshot
        if not self._draw_list:
            return 0.0
        start = time.perf_counter()
        drawn = False
        bounds = None
        scene_key = None
        keys = set()
        size = int(snapshot.settings.shadow_map_size)
        for index, light in enumerate(snapshot.lights):
            if not light.cast_shadows:
                continue
            if scene_key is None:
                scene_key = shadow_scene_key(snapshot)
            key = shadow_key(light, scene_key, size)
            keys.add(key)
            atlas = self.resources.shadow_atlas(key)
            if atlas is None:
                if bounds is None:
                    bounds = snapshot.bounds()
                atlas = self._render_atlas(gpu, light, bounds, size)
                self.resources.put_shadow_atlas(key, atlas)
                drawn = True
            self.atlases[index] = atlas
        self.resources.retain_shadows(keys)
        return _ms(start) if drawn else 0.0

    def _render_atlas(self, gpu, light, bounds, size) -> ShadowAtlas:
        views = light_views(light, bounds, size)
        face = views[0].size
        columns = min(len(views), shaders.ATLAS_COLUMNS)
        rows = -(-len(views) // shaders.ATLAS_COLUMNS)
        atlas_size = (face * columns, face * rows)
        texture = gpu.types.GPUTexture(atlas_size, format="R32F")
        depth = gpu.types.GPUTexture(atlas_size, format="DEPTH_COMPONENT32F")
        framebuffer = gpu.types.GPUFrameBuffer(depth_slot=depth, color_slots=(texture,))
        shader = self._shaders["shadow"]
        with framebuffer.bind():
            framebuffer.clear(color=(float(max(v.far for v in views)), 0.0, 0.0, 0.0), depth=1.0)
            gpu.state.depth_test_set("LESS_EQUAL")
            gpu.state.depth_mask_set(True)
            # Two-sided: cards and open meshes must cast from both sides.
            gpu.state.face_culling_set("NONE")
            gpu.state.blend_set("NONE")
            shader.bind()
            for tile, view in enumerate(views):
                column, row = tile % shaders.ATLAS_COLUMNS, tile // shaders.ATLAS_COLUMNS
                gpu.state.viewport_set(column * face, row * face, face, face)
                ubo = _ubo(gpu, np.r_[np.asarray(_matrix_list(view.view_proj_relative), np.float32),
                                      view.view[2, :3].astype(np.float32), np.float32(0.0)])
                shader.uniform_block("frame", ubo)
                for mesh, groups, _ in self._draw_list:
                    shader.uniform_float("model", _matrix_list(_model_relative(mesh.matrix_world, view.origin)))
                    for material_index, _, batches, _ in groups:
                        if rules.casts_shadow(self.snapshot.materials[material_index]):
                            for batch in batches:
                                batch.draw(shader)
            gpu.state.depth_test_set("NONE")
            gpu.state.depth_mask_set(False)
        gpu.state.viewport_set(0, 0, self.width, self.height)
        del framebuffer, depth
        return ShadowAtlas(texture=texture, views=views, face_size=face)

    def read_shadow_maps(self) -> dict:
        """The shadow maps as numpy ``ShadowMap``s (the reference lighting and tests only)."""
        gpu = gpu_module()
        result = {}
        for index, atlas in self.atlases.items():
            width, height = atlas.texture.width, atlas.texture.height
            framebuffer = gpu.types.GPUFrameBuffer(color_slots=(atlas.texture,))
            buffer = gpu.types.Buffer("FLOAT", width * height)
            with framebuffer.bind():
                framebuffer.read_color(0, 0, width, height, 1, 0, "FLOAT", data=buffer)
            texels = np.asarray(buffer, dtype=np.float32).reshape(height, width)
            maps = []
            for tile, view in enumerate(atlas.views):
                column, row = tile % shaders.ATLAS_COLUMNS, tile // shaders.ATLAS_COLUMNS
                face = atlas.face_size
                maps.append(ShadowMap.from_linear(view, texels[row * face:(row + 1) * face,
                                                               column * face:(column + 1) * face]))
            result[index] = maps
        return result

    # -- lighting and composite ------------------------------------------------------
    def _texture(self, gpu, image):
        image = np.ascontiguousarray(image, dtype=np.float32)
        height, width = image.shape[:2]
        buffer = gpu.types.Buffer("FLOAT", image.size, image.ravel())
        self.resources.created["traced"] += 1
        self.resources.freed["traced"] += 1  # dropped with this frame
        return gpu.types.GPUTexture((width, height), format="RGBA32F" if image.ndim == 3 else "R32F", data=buffer)

    def _upload_traced(self, gpu, traced):
        """Textures of what the tracer computed: per light and layer a visibility image (-1 where
        the shadow map stays), reflection and refraction radiance (alpha 1 where traced)."""
        n = self.width * self.height
        uploads = {"visibility": {}, "reflection": {}, "refraction": None}
        if traced is None:
            return uploads
        for (layer, light_index), (pixels, visibility) in traced.shadow_visibility.items():
            image = np.full(n, -1.0, np.float32)
            image[pixels] = visibility
            uploads["visibility"][(layer, light_index)] = self._texture(gpu, image.reshape(self.height, self.width))
        for layer, (pixels, radiance) in traced.reflection.items():
            image = np.zeros((n, 4), np.float32)
            image[pixels, :3] = radiance
            image[pixels, 3] = 1.0
            uploads["reflection"][layer] = self._texture(gpu, image.reshape(self.height, self.width, 4))
        if traced.refraction is not None:
            pixels, radiance = traced.refraction
            image = np.zeros((n, 4), np.float32)
            image[pixels, :3] = radiance
            image[pixels, 3] = 1.0
            uploads["refraction"] = self._texture(gpu, image.reshape(self.height, self.width, 4))
        return uploads

    def _light_ubo(self, gpu, index, light):
        camera_position = self.snapshot.camera.position
        values = np.zeros((LIGHT_UBO_FLOATS,), np.float32)
        atlas = self.atlases.get(index) if light.cast_shadows else None
        if atlas is not None:
            for face, view in enumerate(atlas.views):
                values[face * 16:(face + 1) * 16] = _matrix_list(view.view_proj_relative)
                values[96 + face * 4:96 + face * 4 + 3] = view.view[2, :3]
        tail = values[120:]
        tail[0:3] = light.color
        tail[3] = shaders.LIGHT_KIND_CODES.get(light.kind, 1)
        tail[4:7] = np.asarray(light.position, np.float64) - camera_position
        tail[7] = max(float(light.radius), 1e-3)
        tail[8:11] = shading.normalize(np.asarray(light.direction, dtype=np.float64))
        if light.kind == "SPOT":
            outer = np.cos(light.spot_size / 2.0)
            blend = max(float(light.spot_blend), 1e-4)
            tail[12] = outer
            tail[13] = outer + (1.0 - outer) * blend
        tail[14] = 1.0 if atlas is not None else 0.0
        if atlas is not None:
            view = atlas.views[0]
            tail[16:19] = camera_position - view.origin
            tail[19] = len(atlas.views)
            tail[20:24] = (view.texel_angle, view.near, 1.0 if view.ortho else 0.0, atlas.face_size)
        return values

    def _light(self, gpu, uploads):
        """Each layer's light target: full-screen passes of up to LIGHTS_PER_PASS lights; the
        transparent layer's passes are depth-tested against its mask, so they shade only the
        pixels it covers (llvmpipe, like a GPU, skips tiles that fail an early depth test,
        where a branch in the shader would run masked over every pixel)."""
        targets = self.targets
        lights = self.snapshot.lights
        layers = ("opaque", "transparent") if self._transparent_drawn else ("opaque",)
        fused = self._fused and bool(lights)
        framebuffers = {}
        for layer in layers:
            slots = (targets[f"{layer}_light"],)
            if fused and layer == "opaque":
                slots += (targets["combined"],)
            if self._measure:
                slots += (targets["shadow_change"],)  # without the attachment, out_change is discarded
                if fused and layer == "opaque":
                    slots += (targets["traced_change"],)
            framebuffers[layer] = gpu.types.GPUFrameBuffer(
                color_slots=slots, depth_slot=targets["transparent_mask"] if layer == "transparent" else None)
            # The first pass writes every pixel the composite reads (the whole frame for the opaque
            # layer, the masked pixels for the transparent one) and later ones add to it; a target
            # is cleared only when nothing writes it or when it sums both layers (the change).
            if self._measure or not lights:
                with framebuffers[layer].bind():
                    framebuffers[layer].clear(color=(0.0, 0.0, 0.0, 0.0))
        if not lights:
            return
        camera_ubo = self._camera_ubo(gpu, self._traced_flags)
        no_shadow_map = self.resources.placeholder(-1.0)
        no_visibility, empty = targets["no_visibility"], targets["no_radiance"]
        per_pass = shaders.LIGHTS_PER_PASS
        groups = []  # (shader, its batch, the lights' UBO, light indices) per pass
        for first, name in zip(range(0, len(lights), per_pass), self._lighting_names):
            indices = range(first, min(first + per_pass, len(lights)))
            values = np.zeros((per_pass, LIGHT_UBO_FLOATS), np.float32)
            for slot, index in enumerate(indices):
                values[slot] = self._light_ubo(gpu, index, lights[index])
            shader = self._shaders[name]
            # Referenced until drawn: a dropped UBO reads as zeros.
            groups.append((shader, self.resources.fullscreen_batch(shader), _ubo(gpu, values.ravel()), indices))
        try:
            for layer in layers:
                with framebuffers[layer].bind():
                    gpu.state.viewport_set(0, 0, self.width, self.height)
                    # The full-screen triangle sits at depth 0.5: it passes where the mask is 0.
                    gpu.state.depth_test_set("GREATER" if layer == "transparent" else "NONE")
                    gpu.state.depth_mask_set(False)
                    for number, (shader, batch, light_ubo, indices) in enumerate(groups):
                        gpu.state.blend_set("ADDITIVE_PREMULT" if number > 0 or self._measure else "NONE")
                        if fused and layer == "opaque":
                            # The one pass of the opaque layer writes Combined too: not blended.
                            gpu.state.blend_set("NONE")
                            shader = self._shaders[self._lighting_names[-1]]
                            batch = self.resources.fullscreen_batch(shader)
                        shader.bind()
                        shader.uniform_block("camera", camera_ubo)
                        shader.uniform_block("lights", light_ubo)
                        for name in ("position", "normal", "albedo"):
                            shader.uniform_sampler(f"layer_{name}", targets[f"{layer}_{name}"])
                        shader.uniform_sampler("material_table", self.material_table)
                        shader.uniform_int("measure_change", int(self._measure))
                        traced = 0
                        for slot, index in enumerate(indices):
                            visibility = uploads["visibility"].get((layer, index))
                            atlas = self.atlases.get(index)
                            traced |= (visibility is not None) << slot
                            shader.uniform_sampler(f"shadow_map{slot}",
                                                   atlas.texture if atlas is not None else no_shadow_map)
                            shader.uniform_sampler(f"visibility{slot}",
                                                   visibility if visibility is not None else no_visibility)
                        shader.uniform_int("traced_lights", traced)
                        if fused and layer == "opaque":
                            shader.uniform_sampler("opaque_reflection", uploads["reflection"].get("opaque", empty))
                        batch.draw(shader)
                    gpu.state.depth_test_set("NONE")
        finally:
            gpu.state.blend_set("NONE")

    def _composite(self, gpu, uploads) -> np.ndarray:
        targets = self.targets
        slots = (targets["combined"], targets["traced_change"]) if self._measure else (targets["combined"],)
        framebuffer = gpu.types.GPUFrameBuffer(color_slots=slots)
        camera_ubo = self._camera_ubo(gpu, self._traced_flags)
        empty = targets["no_radiance"]

        def bind(shader, with_transparent):
            shader.uniform_block("camera", camera_ubo)
            for layer in ("opaque", "transparent") if with_transparent else ("opaque",):
                for name in ("position", "normal", "albedo", "light"):
                    shader.uniform_sampler(f"{layer}_{name}", targets[f"{layer}_{name}"])
                shader.uniform_sampler(f"{layer}_reflection", uploads["reflection"].get(layer, empty))
            if with_transparent:
                shader.uniform_sampler("refraction", uploads["refraction"] or empty)
            shader.uniform_sampler("material_table", self.material_table)
            shader.uniform_sampler("shadow_change", targets["shadow_change"] if self._measure else empty)
            shader.uniform_int("measure_change", int(self._measure))

        gpu.state.blend_set("NONE")
        # The opaque layer over the whole frame, then both layers where the transparent one
        # covers the pixel (the pixels its mask lets through are drawn again, in full).
        if not (self._fused and self.snapshot.lights):  # else the lighting pass composited it
            self._fullscreen(gpu, "composite_opaque", framebuffer, lambda shader: bind(shader, False))
        if self._transparent_drawn:
            masked = gpu.types.GPUFrameBuffer(color_slots=slots, depth_slot=targets["transparent_mask"])
            self._fullscreen(gpu, "composite", masked, lambda shader: bind(shader, True), depth_test="GREATER")
        return self._read(gpu, framebuffer, 0, "FLOAT", 4) if self.read_combined else None

    # -- read-back ------------------------------------------------------------------
    def _read(self, gpu, framebuffer, slot, kind, channels):
        n = self.width * self.height * channels
        buffer = gpu.types.Buffer(kind, n)
        with framebuffer.bind():
            framebuffer.read_color(0, 0, self.width, self.height, channels, slot, kind, data=buffer)
        dtype = np.float32 if kind == "FLOAT" else np.uint32
        shape = (self.height, self.width, channels) if channels > 1 else (self.height, self.width)
        # The array keeps the buffer it views alive: no copy.
        return np.asarray(buffer, dtype=dtype).reshape(shape)

    def _read_layer(self, gpu, framebuffer, first_slot) -> GBufferLayer:
        position = self._read(gpu, framebuffer, first_slot, "FLOAT", 4)
        normal = self._read(gpu, framebuffer, first_slot + 1, "FLOAT", 4)
        element = self._read(gpu, framebuffer, first_slot + 2, "UINT", 1)
        return decode_layer(position, normal, element)


def decode_layer(position: np.ndarray, normal: np.ndarray, element: np.ndarray, albedo=None) -> GBufferLayer:
    """The raw read-back targets as a ``GBufferLayer`` (whole-array numpy).  Cleared pixels
    read as zeros in every target."""
    material = np.rint(position[..., 3]).astype(np.int64) - 1
    covered = material >= 0
    return GBufferLayer(
        covered=covered,
        position=np.ascontiguousarray(position[..., :3]),
        normal=np.ascontiguousarray(normal[..., :3]),
        roughness=np.ascontiguousarray(normal[..., 3]),
        albedo=None if albedo is None else np.ascontiguousarray(albedo[..., :3]),
        metallic=None if albedo is None else np.ascontiguousarray(albedo[..., 3]),
        material=material.astype(np.int32),
        element=element.astype(np.int64) - 1,
    )
