"""The G-buffer pass: the opaque layer, then the nearest transparent surfaces in front of it, then
the resolve that writes the front element, normal and depth (read back for the selection's A,
P, D and the Normal and Depth passes) and the transparent layer's mask.

Chunks of a mesh wholly outside the view are not drawn (``phrt_addon/raster/draw_chunks.py``: one
test per mesh and frame).  The layout of the targets is ``surface_glsl``'s.
"""
from __future__ import annotations

import numpy as np

from ...phrt_addon.raster import draw_chunks
from . import fullscreen, readback, uniforms

TEXTURED, UNTEXTURED, RESOLVE = "gbuffer", "gbuffer_untextured", "resolve"
# The variants that also write the face normal (the "geometric" targets), where the trace stage's
# rays leave from: atrium RAYTRACE at 320x240, the trace stage 35.2 -> 30.9 ms a frame (the
# normals from neighbouring positions on the CPU took 7 ms, and straddled edges of curved
# surfaces), the G-buffer pass and its read-back 0.6 ms more.  Drawn only by frames that may trace.
FACES = "_faces"

# What the id targets can tell apart: element index + 1 ("none" = 0) in the 32-bit element target,
# material index + 1 in the float position target's w (exact to 2^24).
MAX_ELEMENTS = 0xFFFFFFFF - 1
MAX_MATERIALS = (1 << 24) - 1

# A texture as both paths sample it (phrt_addon/scene/rules.py: the image prepared once, no mipmaps).
SAMPLE_TEXTURE = """
// numpy twin: phrt_addon/scene/rules.py sample_texture (bilinear, wrapping, non-finite coordinates read 0)
vec4 phrt_sample_texture(sampler2D tex, vec2 uv)
{
  if (isnan(uv.x) || isinf(uv.x)) { uv.x = 0.0; }
  if (isnan(uv.y) || isinf(uv.y)) { uv.y = 0.0; }
  ivec2 size = textureSize(tex, 0);
  vec2 position = (uv - floor(uv)) * vec2(size) - 0.5;
  vec2 cell = floor(position);
  vec2 f = position - cell;
  ivec2 c0 = ivec2(cell);  /* in [-1, size - 1]: GLSL's % is undefined for negative operands */
  if (c0.x < 0) { c0.x += size.x; }
  if (c0.y < 0) { c0.y += size.y; }
  ivec2 c1 = (c0 + 1) % size;
  vec4 bottom = mix(texelFetch(tex, ivec2(c0.x, c0.y), 0), texelFetch(tex, ivec2(c1.x, c0.y), 0), f.x);
  vec4 top = mix(texelFetch(tex, ivec2(c0.x, c1.y), 0), texelFetch(tex, ivec2(c1.x, c1.y), 0), f.x);
  return mix(bottom, top, f.y);
}
"""

GBUFFER_VERT = """
// numpy twin: phrt_addon/raster/gbuffer.py GBufferLayer (position relative to the camera, as the tracer's hits)
void main() {
  vec4 world = model * vec4(pos, 1.0);
  v_position = world.xyz;
  v_normal = transpose(inverse(mat3(model))) * nor;
  v_uv = uv;
  gl_Position = frame.view_proj * world;
}
"""

GBUFFER_FRAG = SAMPLE_TEXTURE + """
// numpy twin: phrt_addon/raster/gbuffer.py GBufferLayer (what one layer holds per pixel)
void main() {
  vec3 n = normalize(v_normal);
  if (!gl_FrontFacing) { n = -n; }
  vec4 albedo = base_color;
  /* Sampled exactly as the tracer samples (phrt_sample_texture: bilinear, wrapping).  A
     variant per case, not a branch: llvmpipe runs a branch's body for every fragment, and the
     sampling was 15% of arcade's G-buffer pass where most materials have no texture. */
#if WITH_TEXTURE
  albedo *= phrt_sample_texture(base_tex, v_uv);
#endif
  albedo = clamp(albedo, 0.0, 1.0);
  out_position = vec4(v_position, float(ids.x + 1));
  out_normal = vec4(n, params.x);
  /* 8 bits per channel of sqrt(albedo): a game G-buffer's precision, where it matters (darks). */
  out_albedo = vec4(sqrt(albedo.rgb), clamp(params.y, 0.0, 1.0));
  out_element = uint(ids.y + 1);
#if WITH_FACES
  /* The face normal, for the rays that leave this surface: the position's screen derivatives lie
     in the triangle's plane (a 2x2 quad's helper pixels extrapolate the same triangle).  Camera
     relative positions keep them precise at any world coordinate.  Stored as
     phrt_addon/raster/gbuffer.py encode_face_normals (unorm8: (n + 1) / 2, alpha 0 where
     degenerate: the tracer then leaves towards the camera). */
  vec3 face = cross(dFdx(v_position), dFdy(v_position));
  float face_length = length(face);
  bool usable = face_length > 0.0 && !isinf(face_length) && !isnan(face_length);
  out_geometric = usable ? vec4(face / face_length * 0.5 + 0.5, 1.0) : vec4(0.5, 0.5, 0.5, 0.0);
#endif
}
"""

RESOLVE_FRAG = """
// numpy twin: phrt_addon/raster/gbuffer.py GBuffer.front_element (and front_normal, view_depth)
void main() {
  ivec2 pixel = ivec2(gl_FragCoord.xy);
  vec4 opaque = texelFetch(opaque_position, pixel, 0);
  vec4 transparent = texelFetch(transparent_position, pixel, 0);
  bool front_transparent = transparent.w > 0.5;
  vec4 front = front_transparent ? transparent : opaque;
  vec3 normal = front_transparent ? texelFetch(transparent_normal, pixel, 0).xyz
                                  : texelFetch(opaque_normal, pixel, 0).xyz;
  float depth = front.w > 0.5 ? dot(front.xyz, camera.forward_ortho.xyz) : 1e10;
  out_normal_depth = vec4(front.w > 0.5 ? normal : vec3(0.0), depth);
  out_element = front_transparent ? texelFetch(transparent_element, pixel, 0).r
                                  : texelFetch(opaque_element, pixel, 0).r;
  /* The transparent layer's mask for the lighting passes: near where it covers the pixel. */
  gl_FragDepth = front_transparent ? 0.0 : 1.0;
}
"""


def build(gpu, textured=True, faces=False):
    """The G-buffer pass; ``textured``: the base colour is multiplied by ``base_tex`` (the
    variant for materials with an image; the other reads no texture); ``faces``: also writes the
    face normal (a fifth target)."""
    info = gpu.types.GPUShaderCreateInfo()
    info.define("WITH_TEXTURE", "1" if textured else "0")
    info.define("WITH_FACES", "1" if faces else "0")
    info.typedef_source(uniforms.glsl("FrameData", uniforms.FRAME))
    info.uniform_buf(0, "FrameData", "frame")
    info.push_constant("MAT4", "model")
    info.push_constant("VEC4", "base_color")
    info.push_constant("VEC4", "params")  # roughness, metallic, has_texture, unused
    info.push_constant("IVEC2", "ids")  # material index, element index (-1: none)
    if textured:
        info.sampler(0, "FLOAT_2D", "base_tex")
    interface = gpu.types.GPUStageInterfaceInfo("phrt_gbuffer_iface")
    interface.smooth("VEC3", "v_position")
    interface.smooth("VEC3", "v_normal")
    interface.smooth("VEC2", "v_uv")
    info.vertex_in(0, "VEC3", "pos")
    info.vertex_in(1, "VEC3", "nor")
    info.vertex_in(2, "VEC2", "uv")
    info.vertex_out(interface)
    info.fragment_out(0, "VEC4", "out_position")
    info.fragment_out(1, "VEC4", "out_normal")
    info.fragment_out(2, "VEC4", "out_albedo")
    info.fragment_out(3, "UINT", "out_element")
    if faces:
        info.fragment_out(4, "VEC4", "out_geometric")
    info.vertex_source(GBUFFER_VERT)
    info.fragment_source(GBUFFER_FRAG)
    return gpu.shader.create_from_info(info)


def build_resolve(gpu):
    return fullscreen.build(gpu, uniforms.glsl("CameraData", uniforms.CAMERA), (),
                            (("VEC4", "out_normal_depth"), ("UINT", "out_element")), RESOLVE_FRAG,
                            layers={"with_albedo": False, "with_element": True}, depth_write="ANY")


BUILDERS = {TEXTURED: build, UNTEXTURED: lambda gpu: build(gpu, textured=False),
            TEXTURED + FACES: lambda gpu: build(gpu, faces=True),
            UNTEXTURED + FACES: lambda gpu: build(gpu, textured=False, faces=True), RESOLVE: build_resolve}


def draws_faces(snapshot) -> bool:
    """Whether a frame of ``snapshot`` writes the face normals: when it may trace (not RASTER,
    some element a candidate)."""
    return str(snapshot.settings.mode).upper() != "RASTER" and any(e.is_candidate for e in snapshot.elements)


def unused_shaders(faces: bool) -> tuple:
    """The G-buffer variants a frame with or without face normals does not bind."""
    return (TEXTURED, UNTEXTURED) if faces else (TEXTURED + FACES, UNTEXTURED + FACES)


def view_proj(camera):
    """Projection @ view with the camera at the origin: positions relative to the camera keep
    float32 precision at any world coordinate."""
    view_relative = camera.view_matrix.copy()
    view_relative[:3, 3] = (camera.view_matrix @ np.r_[camera.position, 1.0])[:3]
    return np.asarray(camera.projection, dtype=np.float64) @ view_relative


def draw(gpu, frame) -> bool:
    """Both layers of ``frame`` into its targets; sets ``frame.stats`` chunks_drawn and
    chunks_culled; returns whether a transparent layer was drawn."""
    targets = frame.targets
    snapshot = frame.snapshot
    origin = snapshot.camera.position
    projection = view_proj(snapshot.camera)
    ubo = uniforms.frame_block(gpu, projection)
    transparent = np.array([m.is_transparent for m in snapshot.materials], dtype=bool)
    textured = np.zeros(len(snapshot.materials), bool)
    textured[list(frame.material_textures)] = True
    has_transparent = any(transparent[material] for _, groups, _ in frame.draw_list for material, *_ in groups)
    # Chunks wholly outside the view are not drawn (draw_chunks): one test per mesh and frame.
    visible = []
    for mesh, _, boxes in frame.draw_list:
        model = uniforms.model_relative(mesh.matrix_world, origin)
        visible.append((model, ~draw_chunks.boxes_outside(projection @ model, boxes)))
    drawn = culled = 0
    faces = frame.faces
    names = ("position", "normal", "albedo", "element") + (("geometric",) if faces else ())
    for layer in ("opaque", "transparent"):
        framebuffer = gpu.types.GPUFrameBuffer(
            depth_slot=targets["opaque_depth"],
            color_slots=tuple(targets[f"{layer}_{name}"] for name in names))
        with framebuffer.bind():
            gpu.state.viewport_set(0, 0, frame.width, frame.height)
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
                for name, wanted in ((UNTEXTURED, in_layer & ~textured), (TEXTURED, in_layer & textured)):
                    if not any(wanted[material] for _, groups, _ in frame.draw_list for material, *_ in groups):
                        continue
                    shader = frame.shaders[name + FACES if faces else name]
                    shader.bind()
                    shader.uniform_block("frame", ubo)
                    counts = draw_groups(frame, shader, visible, wanted)
                    drawn, culled = drawn + counts[0], culled + counts[1]
                gpu.state.depth_test_set("NONE")
                gpu.state.depth_mask_set(False)
    frame.stats["chunks_drawn"], frame.stats["chunks_culled"] = drawn, culled
    return has_transparent


def draw_groups(frame, shader, visible, wanted):
    """Draw the visible chunks of the groups whose material is ``wanted``; returns
    (chunks drawn, chunks culled)."""
    drawn = culled = 0
    materials = frame.materials
    for (mesh, groups, _), (model, keep) in zip(frame.draw_list, visible):
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
                shader.uniform_float("model", uniforms.column_major(model))
                model_set = True
            texture = frame.material_textures.get(material_index)
            shader.uniform_float("base_color", (*materials.base_color[material_index], 1.0))
            shader.uniform_float("params", (float(materials.roughness[material_index]),
                                            float(materials.metallic[material_index]),
                                            1.0 if texture is not None else 0.0, 0.0))
            shader.uniform_int("ids", (int(material_index), int(element_index)))
            if texture is not None:
                shader.uniform_sampler("base_tex", texture)
            for batch in shown:
                batch.draw(shader)
    return drawn, culled


def resolve(gpu, frame) -> tuple:
    """The front surface of each pixel: (view depth (inf where nothing), front normal, front
    element (-1: none)) read back; also writes the transparent layer's mask (depth 0 where it
    covers the pixel) that the lighting passes of that layer are depth-tested against."""
    targets = frame.targets
    framebuffer = gpu.types.GPUFrameBuffer(depth_slot=targets["transparent_mask"],
                                           color_slots=(targets["normal_depth"], targets["front_element"]))
    camera_ubo = uniforms.camera_block(gpu, frame.snapshot)

    def bind(shader):
        shader.uniform_block("camera", camera_ubo)
        for layer in ("opaque", "transparent"):
            for name in ("position", "normal", "element"):
                shader.uniform_sampler(f"{layer}_{name}", targets[f"{layer}_{name}"])

    gpu.state.blend_set("NONE")
    fullscreen.draw(gpu, frame, RESOLVE, framebuffer, bind, write_depth=True)
    normal_depth = readback.read(gpu, framebuffer, 0, "FLOAT", 4, frame.width, frame.height)
    element = readback.read(gpu, framebuffer, 1, "UINT", 1, frame.width, frame.height)
    depth = normal_depth[..., 3]
    view_depth = np.where(depth < 1e9, depth, np.inf).astype(np.float32)
    return view_depth, np.ascontiguousarray(normal_depth[..., :3]), element.astype(np.int64) - 1
