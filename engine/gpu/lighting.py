"""The deferred lighting pass: full-screen passes of up to ``LIGHTS_PER_PASS`` lights per
G-buffer layer, added into the layer's light target (``lighting_glsl``).

Each pass's shader is a variant with the kind and the shadow map of each of its lights compiled
in (``lighting_name``): llvmpipe runs both sides of every select, and computing every kind's and
map's terms for every light cost a fifth of arcade's light passes.  The transparent layer's
passes are depth-tested against its mask, so they shade only the pixels it covers.  With all
lights in one pass (and the sampler it needs) the opaque layer's pass also composites
(``fused``): one full-screen pass less.
"""
from __future__ import annotations

import enum

import numpy as np

from ...phrt_addon.scene import lights as light_kinds
from . import fullscreen, light_struct, uniforms
from .lighting_glsl import LIGHTING_FRAG
from .surface_glsl import SURFACE_LIB

# Lights added by one lighting pass (each brings a shadow map and a traced-visibility sampler:
# 3 G-buffer + 1 material + 2 x 6 = the 16 samplers every GL implementation has).  More per pass
# reads the G-buffer and blends fewer times (arcade, 5 lights in 2 passes of 4+1 -> 1 of 5:
# 65 -> 56 CPU-ms on llvmpipe).
LIGHTS_PER_PASS = 6


class MapKind(enum.IntEnum):
    """What shadow lookup a light slot compiles in."""

    NONE = 0  # no map: lit (a light without shadows)
    VIEW = 1  # one view (sun, spot)
    CUBE = 2  # a cube map (point, area)


# A variant's name spells, per light slot, two letters: its kind, then its map.
KIND_LETTERS = {light_kinds.LightKind.SUN: "s", light_kinds.LightKind.POINT: "p", light_kinds.LightKind.SPOT: "t",
                light_kinds.LightKind.AREA: "a"}
MAP_LETTERS = {MapKind.NONE: "n", MapKind.VIEW: "v", MapKind.CUBE: "c"}


def lighting_samplers(light_count: int, with_composite: bool = False) -> int:
    """Samplers a lighting variant binds (see build)."""
    return 4 + 2 * int(light_count) + int(bool(with_composite))


def lighting_name(slots, composite: bool = False) -> str:
    """The name of a lighting variant for ``slots`` [(LightKind, MapKind)], ``composite``: the
    opaque layer's pass that also composites."""
    letters = "".join(KIND_LETTERS[kind] + MAP_LETTERS[shadow] for kind, shadow in slots)
    return f"lighting{len(slots)}{'_composite' if composite else ''}_{letters}"


def build(gpu, slots, with_composite=False):
    """``slots`` [(LightKind, MapKind)] lights over one G-buffer layer (bound as ``layer_*``),
    added to its light target (see ``lighting_name``); ``with_composite``: also the opaque
    layer's composite (all its lights in this one pass), written to Combined (and the traced
    change when measured)."""
    light_count = len(slots)
    info = gpu.types.GPUShaderCreateInfo()
    info.define("LIGHTS_PER_PASS", str(LIGHTS_PER_PASS))
    info.define("WITH_COMPOSITE", "1" if with_composite else "0")
    info.typedef_source(uniforms.glsl("CameraData", uniforms.CAMERA) + light_struct.light_set_glsl())
    info.uniform_buf(0, "CameraData", "camera")
    info.uniform_buf(1, "LightSet", "lights")
    names = ["layer_position", "layer_normal", "layer_albedo", "material_table"]
    for i in range(light_count):
        names += [f"shadow_map{i}", f"visibility{i}"]
    if with_composite:
        names.append("opaque_reflection")
    assert len(names) == lighting_samplers(light_count, with_composite)
    for slot, name in enumerate(names):
        info.sampler(slot, "FLOAT_2D", name)
    fullscreen.define_constants(info)
    for kind in light_kinds.LightKind:
        info.define(f"LIGHT_{kind.name}", str(int(kind)))
    for shadow in MapKind:
        info.define(f"MAP_{shadow.name}", str(int(shadow)))
    info.push_constant("INT", "measure_change")
    info.push_constant("INT", "traced_lights")
    info.vertex_in(0, "VEC2", "pos")
    # Colour targets in this order: light, [combined,] shadow change[, traced change] (the
    # change targets are attached only when measured: the last ones may be missing).
    outputs = ["out_light", "out_combined", "out_change", "out_traced_change"] if with_composite \
        else ["out_light", "out_change"]
    for index, name in enumerate(outputs):
        info.fragment_out(index, "VEC4", name)
    info.vertex_source(fullscreen.FULLSCREEN_VERT)
    info.fragment_source(SURFACE_LIB + LIGHTING_FRAG.replace("PHRT_ADD_LIGHTS\n", "".join(
        f"  total += light_layer({i}, {int(slots[i][0])}, {int(slots[i][1])}, shadow_map{i}, s, "
        f"(traced_lights & {1 << i}) != 0 "
        f"? texelFetch(visibility{i}, pixel, 0).r : -1.0, change);\n" for i in range(light_count))))
    return gpu.shader.create_from_info(info)


def light_counts(n_lights: int) -> list:
    """Lights per lighting pass (LIGHTS_PER_PASS, the rest in the last)."""
    return [min(LIGHTS_PER_PASS, n_lights - first) for first in range(0, n_lights, LIGHTS_PER_PASS)]


def light_slots(lights, atlases) -> list:
    """Per lighting pass, (LightKind, MapKind) of each of ``lights`` (``atlases``: the shadow
    maps by light index), what the pass's shader variant computes."""
    slots = []
    for index, light in enumerate(lights):
        if index % LIGHTS_PER_PASS == 0:
            slots.append([])
        atlas = atlases.get(index) if light.cast_shadows else None
        shadow = MapKind.NONE if atlas is None else (MapKind.CUBE if len(atlas.views) == 6 else MapKind.VIEW)
        slots[-1].append((light_kinds.kind(light), shadow))
    return slots


def shaders(lights, atlases, fused: bool) -> list:
    """[(name, builder)] of the lighting shader of each pass in order (two passes of the same
    lights share one), then (``fused``) the opaque layer's variant that also composites."""
    slots = light_slots(lights, atlases)
    named = [(lighting_name(per_pass), lambda gpu, per_pass=per_pass: build(gpu, per_pass)) for per_pass in slots]
    if fused:
        named.append((lighting_name(slots[0], composite=True), lambda gpu: build(gpu, slots[0], with_composite=True)))
    return named


def light(gpu, frame, uploads):
    """Each layer's light target: full-screen passes of up to LIGHTS_PER_PASS lights; the
    transparent layer's passes are depth-tested against its mask, so they shade only the
    pixels it covers (llvmpipe, like a GPU, skips tiles that fail an early depth test,
    where a branch in the shader would run masked over every pixel).  ``uploads``:
    ``traced_textures.upload``'s."""
    targets = frame.targets
    lights = frame.snapshot.lights
    layers = ("opaque", "transparent") if frame.transparent_drawn else ("opaque",)
    fused = frame.fused and bool(lights)
    framebuffers = {}
    for layer in layers:
        slots = (targets[f"{layer}_light"],)
        if fused and layer == "opaque":
            slots += (targets["combined"],)
        if frame.measure:
            slots += (targets["shadow_change"],)  # without the attachment, out_change is discarded
            if fused and layer == "opaque":
                slots += (targets["traced_change"],)
        framebuffers[layer] = gpu.types.GPUFrameBuffer(
            color_slots=slots, depth_slot=targets["transparent_mask"] if layer == "transparent" else None)
        # The first pass writes every pixel the composite reads (the whole frame for the opaque
        # layer, unblended, the change included; the masked pixels for the transparent one) and
        # later ones add to it; a target is cleared only when nothing writes it or when a first
        # pass adds to it: the transparent layer's, which adds its change to the opaque layer's
        # (its light target cleared alone: one blend state covers every attachment).  Clearing
        # every attached target of both layers cost a measured frame about 1 ms at 320x240.
        if not lights:
            with framebuffers[layer].bind():
                framebuffers[layer].clear(color=(0.0, 0.0, 0.0, 0.0))
        elif frame.measure and layer == "transparent":
            light_only = gpu.types.GPUFrameBuffer(color_slots=(targets["transparent_light"],))
            with light_only.bind():
                light_only.clear(color=(0.0, 0.0, 0.0, 0.0))
    if not lights:
        return
    camera_ubo = uniforms.camera_block(gpu, frame.snapshot, frame.traced_flags)
    no_shadow_map = frame.resources.placeholder(-1.0)
    no_visibility, empty = targets["no_visibility"], targets["no_radiance"]
    camera_position = frame.snapshot.camera.position
    groups = []  # (shader, its batch, the lights' UBO, light indices) per pass
    for first, name in zip(range(0, len(lights), LIGHTS_PER_PASS), frame.lighting_names):
        indices = range(first, min(first + LIGHTS_PER_PASS, len(lights)))
        values = np.zeros((LIGHTS_PER_PASS, uniforms.floats(light_struct.LIGHT)), np.float32)
        for slot, index in enumerate(indices):
            atlas = frame.atlases.get(index) if lights[index].cast_shadows else None
            values[slot] = light_struct.pack(lights[index], atlas, camera_position)
        shader = frame.shaders[name]
        # Referenced until drawn: a dropped UBO reads as zeros.
        groups.append((shader, frame.resources.fullscreen_batch(shader), uniforms.upload(gpu, values.ravel()), indices))
    try:
        for layer in layers:
            with framebuffers[layer].bind():
                gpu.state.viewport_set(0, 0, frame.width, frame.height)
                # The full-screen triangle sits at depth 0.5: it passes where the mask is 0.
                gpu.state.depth_test_set("GREATER" if layer == "transparent" else "NONE")
                gpu.state.depth_mask_set(False)
                for number, (shader, batch, light_ubo, indices) in enumerate(groups):
                    gpu.state.blend_set("ADDITIVE_PREMULT" if number > 0 or (frame.measure and layer == "transparent")
                                        else "NONE")
                    if fused and layer == "opaque":
                        # The one pass of the opaque layer writes Combined too: not blended.
                        gpu.state.blend_set("NONE")
                        shader = frame.shaders[frame.lighting_names[-1]]
                        batch = frame.resources.fullscreen_batch(shader)
                    shader.bind()
                    shader.uniform_block("camera", camera_ubo)
                    shader.uniform_block("lights", light_ubo)
                    for name in ("position", "normal", "albedo"):
                        shader.uniform_sampler(f"layer_{name}", targets[f"{layer}_{name}"])
                    shader.uniform_sampler("material_table", frame.material_table)
                    shader.uniform_int("measure_change", int(frame.measure))
                    traced = 0
                    for slot, index in enumerate(indices):
                        visibility = uploads["visibility"].get((layer, index))
                        atlas = frame.atlases.get(index)
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
