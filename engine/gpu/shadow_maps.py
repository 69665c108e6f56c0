"""The shadow-map pass: each shadowed light's maps drawn into an atlas that stays on the GPU.

A light's maps are drawn only when the light or what its maps see changed (``shadow_key``);
``resources.GPUResources`` keeps them across frames.  Each texel holds the linear light-space
depth (R32F), the depth ``phrt_addon/raster/shadowmap.py`` looks up (its views come from
``shadowmap.light_views``); the lighting pass's ``shadow_lit`` is that lookup in GLSL.
"""
from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass

import numpy as np

from ...phrt_addon.scene import rules
from ...phrt_addon.raster.shadowmap import ShadowMap, light_views
from . import uniforms

# Cube-map shadow atlases hold the six faces in a 3 x 2 grid of tiles.
ATLAS_COLUMNS = 3
SHADER = "shadow"

SHADOW_VERT = """
// numpy twin: phrt_addon/raster/shadowmap.py light_views (each view's view_proj_relative and axis)
void main() {
  vec4 world = model * vec4(pos, 1.0);
  v_axis_depth = -dot(world.xyz, frame.axis.xyz);
  gl_Position = frame.view_proj * world;
}
"""

SHADOW_FRAG = """
// numpy twin: phrt_addon/raster/shadowmap.py ShadowMap (linear: the light-space depth per texel)
void main() {
  out_depth = v_axis_depth;
}
"""


@dataclass
class ShadowAtlas:
    """The shadow maps of one light on the GPU: one view (sun, spot) or six cube faces
    in a 3 x 2 grid of tiles, each texel the linear light-space depth (R32F)."""

    texture: object
    views: list  # shadowmap.LightView per tile
    face_size: int


def build(gpu):
    info = gpu.types.GPUShaderCreateInfo()
    info.typedef_source(uniforms.glsl("FrameData", uniforms.FRAME))
    info.uniform_buf(0, "FrameData", "frame")
    info.push_constant("MAT4", "model")
    interface = gpu.types.GPUStageInterfaceInfo("phrt_shadow_iface")
    interface.smooth("FLOAT", "v_axis_depth")
    info.vertex_in(0, "VEC3", "pos")
    info.vertex_out(interface)
    info.fragment_out(0, "FLOAT", "out_depth")
    info.vertex_source(SHADOW_VERT)
    info.fragment_source(SHADOW_FRAG)
    return gpu.shader.create_from_info(info)


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


def ensure(gpu, frame) -> tuple:
    """({light index: ShadowAtlas} of ``frame``'s shadowed lights, ms spent drawing): the maps
    that are missing (new light, moved light, changed geometry) are drawn, the others reused."""
    atlases = {}
    snapshot = frame.snapshot
    if not frame.draw_list:
        return atlases, 0.0
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
        atlas = frame.resources.shadow_atlas(key)
        if atlas is None:
            if bounds is None:
                bounds = snapshot.bounds()
            atlas = render_atlas(gpu, frame, light, bounds, size)
            frame.resources.put_shadow_atlas(key, atlas)
            drawn = True
        atlases[index] = atlas
    frame.resources.retain_shadows(keys)
    return atlases, ((time.perf_counter() - start) * 1000.0 if drawn else 0.0)


def render_atlas(gpu, frame, light, bounds, size) -> ShadowAtlas:
    """Draw one light's maps (every shadow-casting group of ``frame.draw_list``, two-sided)."""
    views = light_views(light, bounds, size)
    face = views[0].size
    columns = min(len(views), ATLAS_COLUMNS)
    rows = -(-len(views) // ATLAS_COLUMNS)
    atlas_size = (face * columns, face * rows)
    texture = gpu.types.GPUTexture(atlas_size, format="R32F")
    depth = gpu.types.GPUTexture(atlas_size, format="DEPTH_COMPONENT32F")
    framebuffer = gpu.types.GPUFrameBuffer(depth_slot=depth, color_slots=(texture,))
    shader = frame.shaders[SHADER]
    materials = frame.snapshot.materials
    with framebuffer.bind():
        framebuffer.clear(color=(float(max(v.far for v in views)), 0.0, 0.0, 0.0), depth=1.0)
        gpu.state.depth_test_set("LESS_EQUAL")
        gpu.state.depth_mask_set(True)
        # Two-sided: cards and open meshes must cast from both sides.
        gpu.state.face_culling_set("NONE")
        gpu.state.blend_set("NONE")
        shader.bind()
        for tile, view in enumerate(views):
            column, row = tile % ATLAS_COLUMNS, tile // ATLAS_COLUMNS
            gpu.state.viewport_set(column * face, row * face, face, face)
            ubo = uniforms.frame_block(gpu, view.view_proj_relative, view.view[2, :3])
            shader.uniform_block("frame", ubo)
            for mesh, groups, _ in frame.draw_list:
                shader.uniform_float("model", uniforms.column_major(uniforms.model_relative(mesh.matrix_world,
                                                                                         view.origin)))
                for material_index, _, batches, _ in groups:
                    if rules.casts_shadow(materials[material_index]):
                        for batch in batches:
                            batch.draw(shader)
        gpu.state.depth_test_set("NONE")
        gpu.state.depth_mask_set(False)
    gpu.state.viewport_set(0, 0, frame.width, frame.height)
    del framebuffer, depth
    return ShadowAtlas(texture=texture, views=views, face_size=face)


def read(gpu, atlases) -> dict:
    """The maps as numpy ``ShadowMap``s, {light index: [per view]} (the reference lighting and
    tests only)."""
    result = {}
    for index, atlas in atlases.items():
        width, height = atlas.texture.width, atlas.texture.height
        framebuffer = gpu.types.GPUFrameBuffer(color_slots=(atlas.texture,))
        buffer = gpu.types.Buffer("FLOAT", width * height)
        with framebuffer.bind():
            framebuffer.read_color(0, 0, width, height, 1, 0, "FLOAT", data=buffer)
        texels = np.asarray(buffer, dtype=np.float32).reshape(height, width)
        maps = []
        for tile, view in enumerate(atlas.views):
            column, row = tile % ATLAS_COLUMNS, tile // ATLAS_COLUMNS
            face = atlas.face_size
            maps.append(ShadowMap.from_linear(view, texels[row * face:(row + 1) * face,
                                                           column * face:(column + 1) * face]))
        result[index] = maps
    return result
