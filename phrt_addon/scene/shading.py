"""Shading: one physically plausible BRDF for raster lighting and ray hits alike.

The frame's deferred lighting runs on the GPU (GLSL twins of these functions in
``engine/gpu/surface_glsl.py`` and ``lighting_glsl.py``); here the same equations serve the tracer's hits and the
numpy reference raster (``raster/reference_raster.py``) the GLSL is tested
against, so "raster" and "traced" differ only in visibility and in what the
specular lobe sees - never in the BRDF.

BRDF: Lambert diffuse weighted by (1 - metallic)(1 - transmission), plus
GGX / Smith (Schlick-GGX) / Schlick-Fresnel specular with F0 = mix(F0(ior),
base colour, metallic).  Roughness is clamped to ``MIN_ROUGHNESS`` for the
analytic lights (a perfect mirror would give an infinitely thin highlight).

Light units follow Cycles: point, spot and area lights in watts (radiant
intensity P/4pi for point and spot, P cos(theta)/pi for one-sided area), sun in
W/m^2 (irradiance).  The world colour is a uniform environment: it adds
``albedo * world`` diffuse ambient and ``F * world`` specular ambient (the raster
stand-in for reflections that are not ray traced).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import lights, rules

MIN_ROUGHNESS = 0.04
INV_PI = 1.0 / np.pi


def unit_clip(values):
    """``np.clip(values, 0, 1)`` (NaN stays NaN) in two ufunc calls: ``np.clip``'s own overhead
    is several times theirs on the few dozen rays of a deep bounce level."""
    return np.minimum(np.maximum(values, 0.0), 1.0)


def pow5(values):
    """``values ** 5`` as the GLSL twins write it, ``m * m * m * m * m`` (numpy's power calls ``pow``
    per element for an exponent of 5: a quarter of a BRDF evaluation's time).  Within an ulp of
    ``** 5`` in float64, a few in float32 (as the GLSL is)."""
    return values * values * values * values * values


def largest(values):
    """The largest of the last axis's 3 components (``values.max(axis=-1)``, component by
    component: numpy's reduction over an axis of 3 is several times slower)."""
    return np.maximum(np.maximum(values[..., 0], values[..., 1]), values[..., 2])


@dataclass
class SurfaceSamples:
    """N shading points (whole arrays).  Terms every light needs (F0, diffuse weight,
    GGX alpha, n.v) are computed once here instead of once per light.

    GLSL twin: engine/gpu/surface_glsl.py read_surface"""

    position: np.ndarray  # (N,3) world, relative to the caller's origin
    normal: np.ndarray  # (N,3) unit, facing the viewer
    view: np.ndarray  # (N,3) unit, from the surface towards the viewer
    albedo: np.ndarray  # (N,3)
    metallic: np.ndarray  # (N,)
    roughness: np.ndarray  # (N,)
    transmission: np.ndarray  # (N,)
    ior: np.ndarray  # (N,)
    emission: np.ndarray  # (N,3)

    def __post_init__(self):
        self.f0 = specular_f0(self.albedo, self.metallic, self.ior)
        self.diffuse_weight = (1.0 - self.metallic) * (1.0 - self.transmission)
        self.diffuse_color = self.albedo * (self.diffuse_weight * INV_PI)[:, None]
        self.alpha = np.maximum(self.roughness, MIN_ROUGHNESS) ** 2
        self.n_dot_v = np.minimum(np.maximum(dot(self.normal, self.view), 1e-4), 1.0)

    def __len__(self):
        return len(self.position)

    BRDF_FIELDS = ("normal", "view", "alpha", "n_dot_v", "f0", "diffuse_color")

    def repeated(self, times: int) -> "SurfaceSamples":
        """The samples ``times`` over, one after the other, with just what ``brdf_cosine`` reads:
        every light of a batch of hits in one call (tracer.py ``direct``)."""
        if times == 1:
            return self
        part = object.__new__(SurfaceSamples)
        for name in self.BRDF_FIELDS:
            value = self.__dict__[name]
            part.__dict__[name] = np.tile(value, (times,) + (1,) * (value.ndim - 1))
        return part

    def subset(self, index) -> "SurfaceSamples":
        """The samples at ``index`` with just what ``brdf_cosine`` reads (precomputed terms are
        sliced, not recomputed; nothing is copied when ``index`` takes every sample)."""
        if len(index) == len(self):
            return self
        part = object.__new__(SurfaceSamples)
        for name in self.BRDF_FIELDS:
            part.__dict__[name] = self.__dict__[name][index]
        return part


def dot(a, b):
    """Row-wise dot product of (N,3) arrays (component by component: about twice as fast as
    ``einsum`` over tens of thousands of rows)."""
    a, b = np.asarray(a), np.asarray(b)
    if a.ndim != 2 or a.shape[-1] != 3 or b.shape != a.shape:
        return np.einsum("ij,ij->i", a, b)
    return a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]


class MaterialTable:
    """Per-material parameters as arrays indexed by material index.

    GLSL twin: engine/gpu/surface_glsl.py material_row"""

    def __init__(self, materials):
        count = max(len(materials), 1)
        self.base_color = np.full((count, 3), 0.8)
        self.metallic = np.zeros(count)
        self.roughness = np.full(count, 0.5)
        self.transmission = np.zeros(count)
        self.ior = np.full(count, 1.5)
        self.alpha = np.ones(count)
        self.emission = np.zeros((count, 3))
        for index, material in enumerate(materials):
            self.base_color[index] = material.base_color[:3]
            self.metallic[index] = material.metallic
            self.roughness[index] = material.roughness
            self.transmission[index] = material.transmission
            self.ior[index] = material.ior
            self.alpha[index] = material.alpha
            self.emission[index] = material.emission[:3]
        self.base_color = rules.unit_interval(self.base_color)
        self.metallic = rules.unit_interval(self.metallic)
        self.roughness = rules.unit_interval(self.roughness)
        self.transmission = rules.unit_interval(self.transmission)
        self.alpha = rules.unit_interval(self.alpha, nan=1.0)
        self.ior = rules.clamp_ior(self.ior)
        np.nan_to_num(self.emission, copy=False, nan=0.0, posinf=0.0, neginf=0.0)
        np.clip(self.emission, 0.0, 1e6, out=self.emission)
        # The rules of phrt_addon/scene/rules.py, per material.
        self.transmissive = rules.transmissive(self.transmission, self.metallic)
        self.transparent = rules.is_transparent_values(self.transmission, self.metallic, self.alpha)
        self.casts_shadow = rules.casts_shadow_values(self.transmission, self.metallic, self.alpha)


def normalize(vectors):
    vectors = np.asarray(vectors)
    if vectors.ndim == 1:
        return vectors / max(float(np.sqrt(np.dot(vectors, vectors))), 1e-30)
    if vectors.shape[-1] == 3:  # component by component: about twice as fast as einsum
        length = np.sqrt(vectors[..., 0] * vectors[..., 0] + vectors[..., 1] * vectors[..., 1]
                         + vectors[..., 2] * vectors[..., 2])[..., None]
    else:
        length = np.sqrt(np.einsum("...i,...i->...", vectors, vectors))[..., None]
    return vectors / np.maximum(length, 1e-30)


def f0_dielectric(ior):
    """Reflectance at normal incidence of a dielectric of index ``ior`` (in air).

    GLSL twin: engine/gpu/surface_glsl.py f0_dielectric"""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def specular_f0(albedo, metallic, ior):
    dielectric = f0_dielectric(ior).astype(np.float64)[:, None]  # float64 also for a float32 G-buffer
    return dielectric + (albedo - dielectric) * metallic[:, None]


def specular_f90(f0):
    """Reflectance at grazing incidence: 1, fading to 0 for a surface with (almost) no
    specular reflection at all (F0 below 2%, i.e. IOR below ~1.33; Schlick's 1 at grazing
    would give an IOR-1 surface, which reflects nothing, a bright rim).

    GLSL twin: engine/gpu/surface_glsl.py specular_f90"""
    mean = (f0[..., 0] + f0[..., 1] + f0[..., 2]) / 3.0  # np.mean's order, without its overhead
    return unit_clip(50.0 * mean)[..., None]


def fresnel_schlick(f0, cos_theta):
    """Schlick's Fresnel from ``f0`` towards ``specular_f90(f0)`` at grazing ``cos_theta``.

    GLSL twin: engine/gpu/surface_glsl.py fresnel_schlick"""
    cos_theta = unit_clip(cos_theta)
    return f0 + (specular_f90(f0) - f0) * pow5(1.0 - cos_theta)[:, None]


def fresnel_dielectric(cos_incident, eta):
    """Exact unpolarised Fresnel reflectance for relative IOR ``eta`` = n_transmitted / n_incident.
    Returns 1 under total internal reflection.

    GLSL twin: engine/gpu/surface_glsl.py fresnel_dielectric"""
    cos_i = unit_clip(np.abs(cos_incident))
    sin2_t = (1.0 - cos_i ** 2) / (eta ** 2)
    total = sin2_t > 1.0
    cos_t = np.sqrt(unit_clip(1.0 - sin2_t))
    rs = (cos_i - eta * cos_t) / np.maximum(cos_i + eta * cos_t, 1e-30)
    rp = (eta * cos_i - cos_t) / np.maximum(eta * cos_i + cos_t, 1e-30)
    # No interface (matching indices) reflects nothing, also at grazing incidence.
    return np.where(total, 1.0, np.where(np.abs(eta - 1.0) < 1e-12, 0.0, 0.5 * (rs ** 2 + rp ** 2)))


def reflect(incident, normal):
    """Mirror ``incident`` (pointing towards the surface) about ``normal``."""
    return incident - (2.0 * dot(incident, normal))[:, None] * normal


def refract(incident, normal, eta):
    """Snell refraction of unit ``incident`` through a surface with unit ``normal`` facing
    the incident side; ``eta`` = n_incident / n_transmitted.  Returns (direction, total_internal_reflection)."""
    cos_i = -dot(incident, normal)
    sin2_t = eta ** 2 * unit_clip(1.0 - cos_i ** 2)
    total = sin2_t > 1.0
    cos_t = np.sqrt(unit_clip(1.0 - sin2_t))
    direction = eta[:, None] * incident + (eta * cos_i - cos_t)[:, None] * normal
    direction = np.where(total[:, None], reflect(incident, normal), direction)
    return normalize(direction), total


def brdf_cosine(surface: SurfaceSamples, light_dir):
    """BRDF times cos(theta_light): (N,3), for unit ``light_dir`` (surface to light).

    GLSL twin: engine/gpu/surface_glsl.py brdf_cosine"""
    n_dot_l = dot(surface.normal, light_dir)
    lit = n_dot_l > 0.0
    n_dot_l = unit_clip(n_dot_l)
    half = surface.view + light_dir
    half /= np.maximum(np.sqrt(dot(half, half)), 1e-12)[:, None]
    n_dot_h = unit_clip(dot(surface.normal, half))
    v_dot_h = unit_clip(dot(surface.view, half))
    alpha = surface.alpha
    alpha2 = alpha * alpha
    denom = n_dot_h * n_dot_h * (alpha2 - 1.0) + 1.0
    k = alpha * 0.5
    n_dot_v = surface.n_dot_v
    # D * G / (4 n.l n.v) with the n.l of G cancelled against the denominator.
    specular_scale = alpha2 / np.maximum(np.pi * denom * denom, 1e-30) \
        / np.maximum(n_dot_l * (1 - k) + k, 1e-30) / (n_dot_v * (1 - k) + k) * 0.25
    fresnel = fresnel_schlick(surface.f0, v_dot_h)
    result = surface.diffuse_color * (1.0 - fresnel) + fresnel * specular_scale[:, None]
    result *= (n_dot_l * lit)[:, None]
    return result


def light_incidence(light, position, origin):
    """For points (N,3, relative to ``origin``): unit direction to the light, distance to it
    (inf for the sun) and the irradiance arriving there (N,3), before shadows and cosine.
    Works in the precision of ``position`` (float32 for camera-relative G-buffer points).

    GLSL twin: engine/gpu/lighting_glsl.py incidence"""
    position = np.asarray(position)
    dtype = position.dtype if position.dtype in (np.float32, np.float64) else np.float64
    color = np.asarray(light.color, dtype=np.float64).astype(dtype)
    n = len(position)
    kind = lights.kind(light)
    if kind is lights.LightKind.SUN:
        direction = -normalize(np.asarray(light.direction, dtype=np.float64)).astype(dtype)
        return np.broadcast_to(direction, (n, 3)), np.full(n, np.inf, dtype), np.broadcast_to(color, (n, 3))
    light_position = (np.asarray(light.position, dtype=np.float64) - origin).astype(dtype)
    to_light = light_position - position
    distance = np.sqrt(dot(to_light, to_light))
    safe = np.maximum(distance, 1e-6)
    direction = to_light / safe[:, None]
    axis = normalize(np.asarray(light.direction, dtype=np.float64)).astype(dtype)
    if kind is lights.LightKind.AREA:
        intensity = unit_clip(-(direction @ axis)) * INV_PI
    else:
        intensity = np.full(n, 0.25 * INV_PI, dtype)
        if kind is lights.LightKind.SPOT:
            cos_angle = -(direction @ axis)
            outer, inner = lights.spot_cone(light)
            spot = unit_clip((cos_angle - outer) / max(inner - outer, 1e-6))
            intensity = intensity * spot * spot * (3.0 - 2.0 * spot)
    # Inverse-square falloff, softened inside a small radius (lights.soft_radius).
    radius = lights.soft_radius(light)
    irradiance = color[None, :] * (intensity / (distance ** 2 + radius ** 2))[:, None]
    return direction, distance, irradiance


def ambient(surface: SurfaceSamples, world_color):
    """Uniform-environment lighting: diffuse ambient plus the raster stand-in for reflections."""
    world = np.asarray(world_color, dtype=np.float64)[None, :]
    fresnel = environment_fresnel(surface.f0, surface.n_dot_v, surface.roughness)
    diffuse = surface.albedo * surface.diffuse_weight[:, None] * (1.0 - fresnel) * world
    return diffuse, fresnel


def environment_fresnel(f0, n_dot_v, roughness):
    """Schlick Fresnel with a roughness-dependent ceiling (rough surfaces reflect less at grazing)."""
    ceiling = np.minimum(np.maximum(1.0 - roughness, largest(f0))[:, None], specular_f90(f0))
    return f0 + (np.maximum(ceiling, f0) - f0) * pow5(1.0 - unit_clip(n_dot_v))[:, None]


def finite(image, limit=1e6):
    """Clamp to finite, non-negative radiance: no NaN or Inf ever leaves a stage.

    GLSL twin: engine/gpu/surface_glsl.py finite_radiance"""
    # fmax takes the number over a NaN: NaN and -inf become 0, +inf the limit.
    return np.minimum(np.fmax(image, 0.0), limit)


def finite_rgba(image, limit=1e6) -> np.ndarray:
    """``image`` as C-ordered float32 RGBA with ``finite`` radiance and alpha 1: the array
    itself (changed in place) when it already is one, else a converted copy."""
    out = np.asarray(image, dtype=np.float32, order="C")
    # The common case (a GPU composite already clamps) costs two reductions, not a rewrite: over
    # the whole contiguous array, alpha included (10x faster than over the strided RGB view; a
    # NaN makes the minimum NaN and the test false).  Any value out of range rewrites the RGB.
    flat = out.reshape(-1)
    if not (flat.size == 0 or (flat.min() >= 0.0 and flat.max() <= limit)):
        out[..., :3] = finite(out[..., :3], limit)
    out[..., 3] = 1.0
    return out
