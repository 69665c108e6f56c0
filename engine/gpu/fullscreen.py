"""What the full-screen passes (resolve, lighting, composite) share: a shader drawn over the
whole frame that reads the G-buffer layers, its create-info and its draw."""
from __future__ import annotations

from ...phrt_addon.raster.shadowmap import DEPTH_BIAS_TEXELS, NORMAL_OFFSET_TEXELS
from .shadow_maps import ATLAS_COLUMNS
from .surface_glsl import MATERIAL_TABLE_WIDTH

FULLSCREEN_VERT = """
// numpy twin: none (two triangles over the frame; numpy shades the pixels as arrays)
void main() {
  gl_Position = vec4(pos, 0.0, 1.0);
}
"""


def define_constants(info):
    """The constants the lighting and composite GLSL is compiled with: the material table's
    layout, the shadow atlas's and the shadow lookup's offsets (``phrt_addon/raster/shadowmap.py``)."""
    info.define("MATERIAL_TABLE_WIDTH", str(MATERIAL_TABLE_WIDTH))
    info.define("ATLAS_COLUMNS", str(ATLAS_COLUMNS))
    info.define("NORMAL_OFFSET_TEXELS", repr(float(NORMAL_OFFSET_TEXELS)))
    info.define("DEPTH_BIAS_TEXELS", repr(float(DEPTH_BIAS_TEXELS)))


def layer_samplers(info, first_slot, with_albedo=True, with_element=False, layers=("opaque", "transparent")):
    """Declare ``<layer>_position``, ``_normal`` (``_albedo``, ``_element``) from ``first_slot``
    on; returns the next free slot."""
    slot = first_slot
    for layer in layers:
        info.sampler(slot, "FLOAT_2D", f"{layer}_position")
        info.sampler(slot + 1, "FLOAT_2D", f"{layer}_normal")
        slot += 2
        if with_albedo:
            info.sampler(slot, "FLOAT_2D", f"{layer}_albedo")
            slot += 1
        if with_element:
            info.sampler(slot, "UINT_2D", f"{layer}_element")
            slot += 1
    return slot


def build(gpu, typedefs, samplers, outputs, fragment_source, *, uniform_blocks=(("CameraData", "camera"),),
          layers=None, constants=False, measure_change=False, depth_write=None, extra_defines=None):
    """A shader drawn over the whole frame (``FULLSCREEN_VERT``) that reads the G-buffer layers:
    ``layers`` are ``layer_samplers`` keywords, ``samplers`` the FLOAT_2D samplers after them,
    ``outputs`` (type, name) per colour target, ``constants``: ``define_constants``."""
    info = gpu.types.GPUShaderCreateInfo()
    info.typedef_source(typedefs)
    for slot, (type_name, name) in enumerate(uniform_blocks):
        info.uniform_buf(slot, type_name, name)
    slot = layer_samplers(info, 0, **(layers or {}))
    for offset, name in enumerate(samplers):
        info.sampler(slot + offset, "FLOAT_2D", name)
    if constants:
        define_constants(info)
    for name, value in (extra_defines or {}).items():
        info.define(name, value)
    if measure_change:
        info.push_constant("INT", "measure_change")
    if depth_write is not None:
        info.depth_write(depth_write)
    info.vertex_in(0, "VEC2", "pos")
    for index, (type_name, name) in enumerate(outputs):
        info.fragment_out(index, type_name, name)
    info.vertex_source(FULLSCREEN_VERT)
    info.fragment_source(fragment_source)
    return gpu.shader.create_from_info(info)


def draw(gpu, frame, name, framebuffer, bind, write_depth=False, depth_test="NONE"):
    """One full-screen pass of ``frame.shaders[name]``; ``bind(shader)`` sets its inputs;
    ``write_depth``: the shader's gl_FragDepth is kept; ``depth_test``: the pass (at depth 0.5)
    is drawn where it passes the attached depth."""
    shader = frame.shaders[name]
    with framebuffer.bind():
        gpu.state.viewport_set(0, 0, frame.width, frame.height)
        # Depth is written only with the test on ("ALWAYS"); the shader sets gl_FragDepth.
        gpu.state.depth_test_set("ALWAYS" if write_depth else depth_test)
        gpu.state.depth_mask_set(write_depth)
        shader.bind()
        bind(shader)
        frame.resources.fullscreen_batch(shader).draw(shader)
        gpu.state.depth_test_set("NONE")
        gpu.state.depth_mask_set(False)
