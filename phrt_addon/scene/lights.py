"""Lights as the numpy shading (``shading.py``), the shadow maps (``raster/shadowmap.py``), the
shadow regions (``trace/shadow_region.py``) and the GPU light packing (``engine/gpu/light_struct.py``)
all see them: the kinds, the spot cone and the soft radius.

``Light.kind`` is Blender's light type ("SUN", "POINT", "SPOT", "AREA"); the GLSL lighting
compares the integer of ``LightKind`` (compiled into each light slot of a lighting variant).
A type this table does not know lights as a point light, on both paths.
"""
from __future__ import annotations

import enum

import numpy as np

# The inverse-square falloff is softened inside this radius at least, so that a light touching a
# surface stays finite (1 / (distance^2 + radius^2)).
MIN_RADIUS = 1e-3
# A spot's blend at least: with no blend the cone's edge would divide by zero.
MIN_SPOT_BLEND = 1e-4


class LightKind(enum.IntEnum):
    """A light's kind; the value is the code the GLSL compares."""

    SUN = 0
    POINT = 1
    SPOT = 2
    AREA = 3


def kind(light) -> LightKind:
    """The kind of ``light`` (a ``scene.Light``); an unknown type is a point light."""
    return LightKind.__members__.get(light.kind, LightKind.POINT)


def soft_radius(light) -> float:
    """The radius that softens the light's inverse-square falloff (at least ``MIN_RADIUS``)."""
    return max(float(light.radius), MIN_RADIUS)


def spot_cone(light) -> tuple:
    """(cos outer, cos inner) of a spot's cone: full strength inside the inner cosine, none
    outside the outer one (``spot_size`` is the full cone angle, ``spot_blend`` the share of it
    that fades)."""
    outer = np.cos(light.spot_size / 2.0)
    blend = max(float(light.spot_blend), MIN_SPOT_BLEND)
    return outer, outer + (1.0 - outer) * blend
