"""The composite pass: emission, ambient, reflections and transparency over the layers' light
targets, with the tracer's reflections and refractions where it traced them; Combined is read
back once (unless the viewport draws it from the GPU).

The opaque layer is drawn over the whole frame (by the lighting pass when it is ``fused``),
then both layers where the transparent one covers the pixel (depth-tested against its mask).
"""
from __future__ import annotations

from . import fullscreen, readback, uniforms
from .surface_glsl import SURFACE_LIB

FULL, OPAQUE = "composite", "composite_opaque"

COMPOSITE_FRAG = """
// numpy twin: phrt_addon/raster/reference_raster.py ReferenceRaster.shade (the composite of both layers)
/* The pixel's colour with the traced terms (``use_traced``) or the raster ones.  The variant
   WITH_TRANSPARENT 0 shades the opaque layer only: it is drawn over the whole frame, and the
   full variant then only where the transparent layer covers the pixel (depth-tested against
   its mask; llvmpipe runs a branch's code for every pixel, so the glass is compiled out). */
vec3 composite_pixel(ivec2 pixel, Surface opaque, Surface transparent, bool use_traced) {
  /* Every term is computed and the covered ones chosen by selects (see shadow_lit). */
  vec4 no_trace = vec4(0.0);
  float transmissive;
  float fresnel_t;
  vec4 traced = use_traced && camera.traced.x > 0.5 ? texelFetch(opaque_reflection, pixel, 0) : no_trace;
  vec3 opaque_color = shade_layer(opaque, texelFetch(opaque_light, pixel, 0).rgb, traced, transmissive, fresnel_t);
  vec3 image = opaque.covered ? opaque_color : camera.world.rgb;
#if WITH_TRANSPARENT
  traced = use_traced && camera.traced.y > 0.5 ? texelFetch(transparent_reflection, pixel, 0) : no_trace;
  vec3 surface_color = shade_layer(transparent, texelFetch(transparent_light, pixel, 0).rgb, traced,
                                   transmissive, fresnel_t);
  /* The transmitted part: straight through in raster, the refracted radiance where traced;
     the 1 - alpha part goes straight on (as the tracer's alpha pass-through does). */
  vec4 traced_refraction = texelFetch(refraction, pixel, 0);
  vec3 refracted = use_traced && camera.traced.z > 0.5 && traced_refraction.a > 0.5 ? traced_refraction.rgb : image;
  vec3 transmitted = (transmissive * (1.0 - fresnel_t)) * transparent.albedo * refracted;
  float alpha = transparent.alpha_blend;
  image = transparent.covered ? alpha * (surface_color + transmitted) + (1.0 - alpha) * image : image;
#endif
  return finite_radiance(image);
}

// numpy twin: phrt_addon/raster/reference_raster.py ReferenceRaster.shade (with measure_change: the traced change)
void main() {
  ivec2 pixel = ivec2(gl_FragCoord.xy);
  Surface opaque = read_surface(texelFetch(opaque_position, pixel, 0), texelFetch(opaque_normal, pixel, 0),
                                texelFetch(opaque_albedo, pixel, 0));
  Surface transparent;
#if WITH_TRANSPARENT
  transparent = read_surface(texelFetch(transparent_position, pixel, 0), texelFetch(transparent_normal, pixel, 0),
                             texelFetch(transparent_albedo, pixel, 0));
#endif
  vec3 image = composite_pixel(pixel, opaque, transparent, true);
  out_combined = vec4(image, 1.0);
  out_change = vec4(0.0);
  if (measure_change != 0) {
    /* What the traced reflections and refractions changed (x) and the traced shadows (y). */
    vec3 raster = composite_pixel(pixel, opaque, transparent, false);
    out_change = vec4(min(dot(abs(image - raster), PHRT_LUMINANCE), 1.0),
                      min(texelFetch(shadow_change, pixel, 0).y, 1.0), 0.0, 0.0);
  }
}
"""


def build(gpu, with_transparent=True):
    """Emission, ambient, reflections and transparency over the accumulated lights; without
    ``with_transparent``, the opaque layer only (see COMPOSITE_FRAG)."""
    samplers = ["material_table", "opaque_light", "opaque_reflection", "shadow_change"]
    if with_transparent:
        samplers += ["transparent_light", "transparent_reflection", "refraction"]
    return fullscreen.build(
        gpu, uniforms.glsl("CameraData", uniforms.CAMERA), samplers, (("VEC4", "out_combined"), ("VEC4", "out_change")),
        SURFACE_LIB + COMPOSITE_FRAG, constants=True, measure_change=True,
        layers={"layers": ("opaque", "transparent") if with_transparent else ("opaque",)},
        extra_defines={"WITH_TRANSPARENT": "1" if with_transparent else "0"})


BUILDERS = {FULL: build, OPAQUE: lambda gpu: build(gpu, with_transparent=False)}


def composite(gpu, frame, uploads):
    """Combined of ``frame`` into its target; returns it read back (h, w, 4), or None when
    ``frame.read_combined`` is off.  ``uploads``: ``traced_textures.upload``'s."""
    targets = frame.targets
    measure = frame.measure
    slots = (targets["combined"], targets["traced_change"]) if measure else (targets["combined"],)
    framebuffer = gpu.types.GPUFrameBuffer(color_slots=slots)
    camera_ubo = uniforms.camera_block(gpu, frame.snapshot, frame.traced_flags)
    empty = targets["no_radiance"]

    def bind(shader, with_transparent):
        shader.uniform_block("camera", camera_ubo)
        for layer in ("opaque", "transparent") if with_transparent else ("opaque",):
            for name in ("position", "normal", "albedo", "light"):
                shader.uniform_sampler(f"{layer}_{name}", targets[f"{layer}_{name}"])
            shader.uniform_sampler(f"{layer}_reflection", uploads["reflection"].get(layer, empty))
        if with_transparent:
            shader.uniform_sampler("refraction", uploads["refraction"] or empty)
        shader.uniform_sampler("material_table", frame.material_table)
        shader.uniform_sampler("shadow_change", targets["shadow_change"] if measure else empty)
        shader.uniform_int("measure_change", int(measure))

    gpu.state.blend_set("NONE")
    # The opaque layer over the whole frame, then both layers where the transparent one
    # covers the pixel (the pixels its mask lets through are drawn again, in full).
    if not (frame.fused and frame.snapshot.lights):  # else the lighting pass composited it
        fullscreen.draw(gpu, frame, OPAQUE, framebuffer, lambda shader: bind(shader, False))
    if frame.transparent_drawn:
        masked = gpu.types.GPUFrameBuffer(color_slots=slots, depth_slot=targets["transparent_mask"])
        fullscreen.draw(gpu, frame, FULL, masked, lambda shader: bind(shader, True), depth_test="GREATER")
    if not frame.read_combined:
        return None
    return readback.read(gpu, framebuffer, 0, "FLOAT", 4, frame.width, frame.height)
