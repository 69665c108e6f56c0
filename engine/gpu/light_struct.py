"""The lights a lighting pass reads: ``LIGHT`` is the one table behind both the GLSL ``LightData``
struct (``light_set_glsl``) and ``pack()``, its floats for one light (no offset written by hand).

The light's maths is the numpy shading's (``phrt_addon/scene/lights.py``: the kind code, the spot
cone, the soft-radius floor); positions are relative to the camera, the shadow views relative
to their own origin, as the G-buffer's positions are.
"""
from __future__ import annotations

import numpy as np

from ...phrt_addon.scene import lights, shading
from .uniforms import Field, Packed, column_major, glsl

# A light's shadow views: six cube faces (point, area) or one (sun, spot).
SHADOW_VIEWS = 6

LIGHT = (
    Field("face_view_proj", "mat4", (("face_view_proj", 16),), count=SHADOW_VIEWS,
          comment="shadow views, acting on positions relative to the view origin"),
    Field("face_axis", "vec4", (("face_axis", 3), ("", 1)), count=SHADOW_VIEWS,
          comment="each view's +Z axis: light-space depth = -dot(p, axis)"),
    Field("color_kind", "vec4", (("color", 3), ("kind", 1)), comment="linear colour * strength, kind code"),
    Field("position_radius", "vec4", (("position", 3), ("radius", 1)),
          comment="camera-relative position, soft radius (lights.soft_radius)"),
    Field("direction", "vec4", (("direction", 3), ("", 1)), comment="unit direction the light travels"),
    Field("spot", "vec4", (("cos_outer", 1), ("cos_inner", 1), ("has_map", 1), ("", 1)),
          comment="cos outer, cos inner (lights.spot_cone), has a shadow map, unused"),
    Field("shadow_offset", "vec4", (("shadow_offset", 3), ("views", 1)),
          comment="camera position - view origin, number of views (0: no map)"),
    Field("shadow_params", "vec4", (("texel_angle", 1), ("near", 1), ("ortho", 1), ("view_size", 1)),
          comment="texel angle, near, orthographic, view size in texels"),
)


def light_set_glsl() -> str:
    """``LightData`` and ``LightSet``, the block of one pass's lights (one after the other), as GLSL."""
    return glsl("LightData", LIGHT) + "struct LightSet {\n  LightData light[LIGHTS_PER_PASS];\n};\n"


def pack(light, atlas, camera_position) -> np.ndarray:
    """``LIGHT``'s floats for ``light`` (a ``scene.Light``) with its shadow maps ``atlas``
    (``shadow_maps.ShadowAtlas``, None without) seen from ``camera_position``."""
    packed = Packed(LIGHT)
    if atlas is not None:
        for face, view in enumerate(atlas.views):
            packed.set("face_view_proj", column_major(view.view_proj_relative), face)
            packed.set("face_axis", view.view[2, :3], face)
    kind = lights.kind(light)
    packed.set("color", light.color)
    packed.set("kind", int(kind))
    packed.set("position", np.asarray(light.position, np.float64) - camera_position)
    packed.set("radius", lights.soft_radius(light))
    packed.set("direction", shading.normalize(np.asarray(light.direction, dtype=np.float64)))
    if kind is lights.LightKind.SPOT:
        outer, inner = lights.spot_cone(light)
        packed.set("cos_outer", outer)
        packed.set("cos_inner", inner)
    packed.set("has_map", 1.0 if atlas is not None else 0.0)
    if atlas is not None:
        view = atlas.views[0]
        packed.set("shadow_offset", camera_position - view.origin)
        packed.set("views", len(atlas.views))
        packed.set("texel_angle", view.texel_angle)
        packed.set("near", view.near)
        packed.set("ortho", 1.0 if view.ortho else 0.0)
        packed.set("view_size", atlas.face_size)
    return packed.values
