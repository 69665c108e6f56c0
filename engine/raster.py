"""Raster stage on Blender's ``gpu`` module: G-buffer layers and shadow maps.

Runs inside ``RenderEngine.render()`` (``bl_use_gpu_context = True`` gives a GPU
context, even in background mode, where llvmpipe serves it on the CPU).

- ``GeometryCache`` (CPU, module level, survives between frames and engine
  instances) keeps each mesh's corner arrays ready for upload, keyed by geometry
  key, so an unchanged mesh is converted once per replay.
- ``RasterPass`` owns the GPU objects of one ``render()`` call (shaders, vertex
  buffers, textures, framebuffers).  Use it as a context manager: everything is
  released before ``render()`` returns, as the GPU module requires.
- Shadow maps are read back once and kept as numpy arrays (``ShadowMapCache``)
  until a light or the geometry it sees changes; the lookups happen in numpy
  (``phrt_addon/shading.py``).

Read-back follows PLATFORM-NOTES: flat ``gpu.types.Buffer`` + reshape.
"""
from __future__ import annotations

import numpy as np

from ..phrt_addon import rules
from ..phrt_addon.gbuffer import GBuffer, GBufferLayer
from ..phrt_addon.scene import SceneSnapshot
from ..phrt_addon.shadowmap import ShadowMap, light_views

GBUFFER_VERT = """
void main() {
  vec4 world = model * vec4(pos, 1.0);
  v_position = world.xyz;
  v_normal = transpose(inverse(mat3(model))) * nor;
  v_uv = uv;
  gl_Position = frame.view_proj * world;
}
"""

GBUFFER_FRAG = rules.GLSL_SAMPLE_TEXTURE + """
void main() {
  vec3 n = normalize(v_normal);
  if (!gl_FrontFacing) { n = -n; }
  vec4 albedo = base_color;
  if (params.z > 0.5) { albedo *= phrt_sample_texture(base_tex, v_uv); }
  albedo = clamp(albedo, 0.0, 1.0);
  out_position = vec4(v_position, 1.0);
  out_normal = vec4(n, params.x);
  /* albedo as 8-bit sqrt-encoded RGB and metallic as 8 bits: enough for shading inputs */
  uvec4 bits = uvec4(round(vec4(sqrt(albedo.rgb), clamp(params.y, 0.0, 1.0)) * 255.0));
  out_ids = uint(ids);
  out_material = bits.r | (bits.g << 8u) | (bits.b << 16u) | (bits.a << 24u);
}
"""

DEPTH_VERT = """
void main() {
  gl_Position = frame.view_proj * (model * vec4(pos, 1.0));
}
"""

DEPTH_FRAG = """
void main() {
}
"""

def _gpu():
    import gpu  # only inside render(): module-level gpu drawing is unavailable in background mode
    return gpu


def pack_ids(material_index: int, element_index: int) -> int:
    """Material (16 bits) and element+1 (15 bits) in one uint; the G-buffer's id target."""
    return ((int(material_index) & 0xFFFF) << 15) | ((int(element_index) + 1) & 0x7FFF)


MAX_ELEMENTS = 0x7FFF - 1
MAX_MATERIALS = 0xFFFF


class GeometryCache:
    """Corner arrays ready for GPU upload, keyed by mesh geometry key (CPU only)."""

    def __init__(self):
        self._entries = {}

    def get(self, mesh):
        entry = self._entries.get(mesh.geometry_key)
        if entry is None:
            corners = mesh.triangles.reshape(-1)
            uvs = rules.texture_coordinates(mesh.corner_uvs, len(corners))
            groups = [(material, element, np.ascontiguousarray(
                (tris[:, None] * 3 + np.arange(3)[None, :]).astype(np.int32)))
                for material, element, tris in mesh.material_groups()]
            entry = {
                "pos": np.ascontiguousarray(mesh.positions[corners], dtype=np.float32),
                "nor": np.ascontiguousarray(mesh.corner_normals, dtype=np.float32),
                "uv": np.ascontiguousarray(uvs, dtype=np.float32),
                "groups": groups,
            }
            self._entries[mesh.geometry_key] = entry
        return entry

    def retain(self, keys):
        """Forget geometry not used by the current frame (bounded memory across scenes)."""
        for key in list(self._entries):
            if key not in keys:
                del self._entries[key]

    def __len__(self):
        return len(self._entries)


class ShadowMapCache:
    """Read-back shadow maps kept between frames while light and geometry are unchanged."""

    def __init__(self):
        self._maps = {}

    def get(self, key):
        return self._maps.get(key)

    def put(self, key, shadow_maps):
        self._maps[key] = shadow_maps

    def retain(self, keys):
        for key in list(self._maps):
            if key not in keys:
                del self._maps[key]


GEOMETRY_CACHE = GeometryCache()
SHADOW_MAP_CACHE = ShadowMapCache()


def _matrix_list(matrix) -> list:
    """Row-major 4x4 -> the column-major flat list GLSL expects."""
    return np.asarray(matrix, dtype=np.float32).T.ravel().tolist()


class RasterPass:
    """GPU resources of one render() call. ``with RasterPass(snapshot) as raster: ...``"""

    def __init__(self, snapshot: SceneSnapshot, geometry_cache: GeometryCache = GEOMETRY_CACHE):
        self.snapshot = snapshot
        self.geometry_cache = geometry_cache
        self.stats = {"upload_ms": 0.0, "triangles": 0}
        self._gpu_objects = []

    # -- lifetime -----------------------------------------------------------
    def __enter__(self):
        import time
        gpu = _gpu()
        start = time.perf_counter()
        self.gbuffer_shader = self._make_shader(gpu, GBUFFER_VERT, GBUFFER_FRAG, gbuffer=True)
        self.depth_shader = self._make_shader(gpu, DEPTH_VERT, DEPTH_FRAG, gbuffer=False)
        white = gpu.types.Buffer("FLOAT", 4, [1.0, 1.0, 1.0, 1.0])
        self.white_texture = gpu.types.GPUTexture((1, 1), format="RGBA32F", data=white)
        self.textures = {}
        self.batches = []  # (mesh, [(material, element, batch)])
        keys = set()
        for mesh in self.snapshot.meshes:
            if mesh.n_triangles == 0:
                continue
            keys.add(mesh.geometry_key)
            self.batches.append((mesh, self._upload(gpu, mesh)))
            self.stats["triangles"] += mesh.n_triangles
        self.geometry_cache.retain(keys)
        self.stats["upload_ms"] = (time.perf_counter() - start) * 1000.0
        return self

    def __exit__(self, *exc):
        # Drop every GPU object while the context is still current.
        self.batches = []
        self.textures = {}
        self.white_texture = None
        self.gbuffer_shader = None
        self.depth_shader = None
        self._gpu_objects.clear()
        return False

    # -- set-up -------------------------------------------------------------
    @staticmethod
    def _make_shader(gpu, vert, frag, gbuffer):
        info = gpu.types.GPUShaderCreateInfo()
        info.typedef_source("struct FrameData { mat4 view_proj; };")
        info.uniform_buf(0, "FrameData", "frame")
        info.push_constant("MAT4", "model")
        info.vertex_in(0, "VEC3", "pos")
        if gbuffer:
            interface = gpu.types.GPUStageInterfaceInfo("phrt_gbuffer_iface")
            interface.smooth("VEC3", "v_position")
            interface.smooth("VEC3", "v_normal")
            interface.smooth("VEC2", "v_uv")
            info.push_constant("VEC4", "base_color")
            info.push_constant("VEC4", "params")  # roughness, metallic, has_texture, unused
            info.push_constant("INT", "ids")
            info.sampler(0, "FLOAT_2D", "base_tex")
            info.vertex_in(1, "VEC3", "nor")
            info.vertex_in(2, "VEC2", "uv")
            info.vertex_out(interface)
            info.fragment_out(0, "VEC4", "out_position")
            info.fragment_out(1, "VEC4", "out_normal")
            info.fragment_out(2, "UINT", "out_ids")
            info.fragment_out(3, "UINT", "out_material")
        info.vertex_source(vert)
        info.fragment_source(frag)
        return gpu.shader.create_from_info(info)

    def _upload(self, gpu, mesh):
        entry = self.geometry_cache.get(mesh)
        fmt = gpu.types.GPUVertFormat()
        fmt.attr_add(id="pos", comp_type="F32", len=3, fetch_mode="FLOAT")
        fmt.attr_add(id="nor", comp_type="F32", len=3, fetch_mode="FLOAT")
        fmt.attr_add(id="uv", comp_type="F32", len=2, fetch_mode="FLOAT")
        vbo = gpu.types.GPUVertBuf(fmt, len(entry["pos"]))
        vbo.attr_fill("pos", entry["pos"])
        vbo.attr_fill("nor", entry["nor"])
        vbo.attr_fill("uv", entry["uv"])
        batches = []
        for material, element, indices in entry["groups"]:
            ibo = gpu.types.GPUIndexBuf(type="TRIS", seq=indices)
            batches.append((material, element, gpu.types.GPUBatch(type="TRIS", buf=vbo, elem=ibo)))
        return batches

    def _texture(self, gpu, material):
        if material.texture is None:
            return None
        key = material.texture_key or material.name
        texture = self.textures.get(key)
        if texture is None:
            image = rules.prepare_texture(material.texture)
            height, width = image.shape[:2]
            buffer = gpu.types.Buffer("FLOAT", width * height * 4, image.ravel())
            texture = gpu.types.GPUTexture((width, height), format="RGBA32F", data=buffer)
            self.textures[key] = texture
        return texture

    # -- drawing ------------------------------------------------------------
    def _frame_ubo(self, gpu, view_proj):
        return gpu.types.GPUUniformBuf(gpu.types.Buffer("FLOAT", 16, _matrix_list(view_proj)))

    @staticmethod
    def _model_relative(matrix_world, origin):
        model = np.array(matrix_world, dtype=np.float64)
        model[:3, 3] -= origin
        return model

    def render_gbuffer(self) -> GBuffer:
        """Draw the opaque layer, read it back, then the nearest transparent surfaces in
        front of it (depth test against the opaque depth), and read those back."""
        gpu = _gpu()
        camera = self.snapshot.camera
        width, height = camera.width, camera.height
        origin = camera.position
        # view @ translate(origin): the camera sits at the origin, so positions relative
        # to it keep float32 precision at any world coordinate.
        view_relative = camera.view_matrix.copy()
        view_relative[:3, 3] = (camera.view_matrix @ np.r_[origin, 1.0])[:3]
        view_proj = np.asarray(camera.projection, dtype=np.float64) @ view_relative
        ubo = self._frame_ubo(gpu, view_proj)

        tex_position = gpu.types.GPUTexture((width, height), format="RGBA32F")
        tex_normal = gpu.types.GPUTexture((width, height), format="RGBA32F")
        tex_ids = gpu.types.GPUTexture((width, height), format="R32UI")
        tex_material = gpu.types.GPUTexture((width, height), format="R32UI")
        tex_depth = gpu.types.GPUTexture((width, height), format="DEPTH_COMPONENT32F")
        framebuffer = gpu.types.GPUFrameBuffer(depth_slot=tex_depth, color_slots=(tex_position, tex_normal, tex_ids, tex_material))
        materials = self.snapshot.materials
        transparent = np.array([m.is_transparent for m in materials], dtype=bool)
        has_transparent = any(transparent[material] for _, groups in self.batches for material, _, _ in groups)
        shader = self.gbuffer_shader
        try:
            with framebuffer.bind():
                framebuffer.clear(color=(0.0, 0.0, 0.0, 0.0), depth=1.0)
                gpu.state.depth_test_set("LESS_EQUAL")
                gpu.state.depth_mask_set(True)
                gpu.state.face_culling_set("NONE")
                gpu.state.blend_set("NONE")
                shader.bind()
                shader.uniform_block("frame", ubo)
                self._draw_groups(gpu, shader, origin, lambda material: not transparent[material])
                opaque = self._read_layer(gpu, framebuffer, width, height)
                if has_transparent:
                    # Keep the opaque depth: only transparent surfaces in front of it pass.
                    framebuffer.clear(color=(0.0, 0.0, 0.0, 0.0))
                    self._draw_groups(gpu, shader, origin, lambda material: bool(transparent[material]))
                    transparent_layer = self._read_layer(gpu, framebuffer, width, height)
                else:
                    transparent_layer = GBufferLayer.empty(width, height)
        finally:
            gpu.state.depth_test_set("NONE")
            gpu.state.depth_mask_set(False)
            del framebuffer, tex_position, tex_normal, tex_ids, tex_material, tex_depth, ubo

        forward = camera.forward
        front = np.where(transparent_layer.covered[..., None], transparent_layer.position, opaque.position)
        covered = opaque.covered | transparent_layer.covered
        view_depth = front.astype(np.float64) @ forward  # distance along the view axis (both projections)
        view_depth = np.where(covered, view_depth, np.inf).astype(np.float32)
        return GBuffer(opaque=opaque, transparent=transparent_layer, origin=origin, view_depth=view_depth)

    def _draw_groups(self, gpu, shader, origin, wanted):
        materials = self.snapshot.materials
        for mesh, groups in self.batches:
            shader.uniform_float("model", _matrix_list(self._model_relative(mesh.matrix_world, origin)))
            for material_index, element_index, batch in groups:
                if not wanted(material_index):
                    continue
                material = materials[material_index]
                texture = self._texture(gpu, material)
                shader.uniform_float("base_color", (*material.base_color[:3], 1.0))
                shader.uniform_float("params", (float(material.roughness), float(material.metallic),
                                                1.0 if texture is not None else 0.0, 0.0))
                shader.uniform_int("ids", pack_ids(material_index, element_index))
                shader.uniform_sampler("base_tex", texture if texture is not None else self.white_texture)
                batch.draw(shader)

    @staticmethod
    def _read_layer(gpu, framebuffer, width, height) -> GBufferLayer:
        n = width * height
        buffer = gpu.types.Buffer("FLOAT", n * 4)
        framebuffer.read_color(0, 0, width, height, 4, 0, "FLOAT", data=buffer)
        position = np.asarray(buffer, dtype=np.float32).reshape(height, width, 4).copy()
        buffer = gpu.types.Buffer("FLOAT", n * 4)
        framebuffer.read_color(0, 0, width, height, 4, 1, "FLOAT", data=buffer)
        normal = np.asarray(buffer, dtype=np.float32).reshape(height, width, 4).copy()
        ids = np.empty((height, width, 2), np.uint32)
        for slot in (2, 3):  # R32UI targets (RG32UI read-back returned zeros on llvmpipe)
            ids_buffer = gpu.types.Buffer("UINT", n)
            framebuffer.read_color(0, 0, width, height, 1, slot, "UINT", data=ids_buffer)
            ids[..., slot - 2] = np.asarray(ids_buffer, dtype=np.uint32).reshape(height, width)
        return decode_layer(position, normal, ids)

    # -- shadow maps --------------------------------------------------------
    def render_shadow_maps(self, light, bounds, size) -> list[ShadowMap]:
        """Depth maps of all geometry seen from ``light`` (1 view for sun/spot, 6 for point/area)."""
        gpu = _gpu()
        maps = []
        shader = self.depth_shader
        for view in light_views(light, bounds, size):
            texture = gpu.types.GPUTexture((view.size, view.size), format="DEPTH_COMPONENT32F")
            framebuffer = gpu.types.GPUFrameBuffer(depth_slot=texture)
            ubo = self._frame_ubo(gpu, view.view_proj_relative)
            try:
                with framebuffer.bind():
                    framebuffer.clear(depth=1.0)
                    gpu.state.depth_test_set("LESS_EQUAL")
                    gpu.state.depth_mask_set(True)
                    # Back faces into the map (front-face culling off: two-sided cards must cast).
                    gpu.state.face_culling_set("NONE")
                    shader.bind()
                    shader.uniform_block("frame", ubo)
                    for mesh, groups in self.batches:
                        shader.uniform_float("model", _matrix_list(self._model_relative(mesh.matrix_world, view.origin)))
                        for material_index, _, batch in groups:
                            if not rules.casts_shadow(self.snapshot.materials[material_index]):
                                continue  # glass, water, alpha cards: rules.casts_shadow
                            batch.draw(shader)
                    buffer = gpu.types.Buffer("FLOAT", view.size * view.size)
                    framebuffer.read_depth(0, 0, view.size, view.size, data=buffer)
                    depth = np.asarray(buffer, dtype=np.float32).reshape(view.size, view.size).copy()
            finally:
                gpu.state.depth_test_set("NONE")
                gpu.state.depth_mask_set(False)
                del framebuffer, texture, ubo
            maps.append(ShadowMap(view=view, depth=depth))
        return maps


def decode_layer(position: np.ndarray, normal: np.ndarray, ids: np.ndarray) -> GBufferLayer:
    """Turn the raw read-back targets into a ``GBufferLayer`` (whole-array numpy).
    Cleared pixels read as zeros in every target, so no masking is needed."""
    covered = position[..., 3] > 0.5  # the shader writes w = 1; cleared pixels are 0
    element = (ids[..., 0] & 0x7FFF).astype(np.int32) - 1
    material = ((ids[..., 0] >> 15) & 0xFFFF).astype(np.int32)
    material[~covered] = -1
    bits = np.ascontiguousarray(ids[..., 1], dtype="<u4")
    packed = bits.view(np.uint8).reshape(bits.shape + (4,))  # little-endian: r, g, b, metallic
    albedo = packed[..., :3].astype(np.float32) * (1.0 / 255.0)
    albedo *= albedo
    return GBufferLayer(
        covered=covered,
        position=np.ascontiguousarray(position[..., :3]),
        normal=np.ascontiguousarray(normal[..., :3]),
        roughness=np.ascontiguousarray(normal[..., 3]),
        albedo=albedo,
        metallic=packed[..., 3].astype(np.float32) * (1.0 / 255.0),
        material=material,
        element=element,
    )
