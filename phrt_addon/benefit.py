"""Expected benefit of ray tracing an element: the error-aware relevance (``relevance = 'error'``).

The paper's relevance knows where an element is (V = A * P / D) but not how
wrong its raster version looks: a mirror facing a bright wall and a matte cube
of the same size get the same V, while only the mirror changes when traced.
This module keeps, per element, a running estimate of how much its traced
image differs from its raster image, per pixel of the element:

- **measured** on frames where the element was traced, from the terms tracing
  replaced (:func:`measure_differences`): its reflections (traced radiance
  against the environment term), its refraction (traced radiance against
  straight-through blending) and the shadows it casts (traced visibility
  against the shadow map, on whatever surface receives them, shared between
  the selected casters whose shadow region holds the pixel).  Differences are
  in linear luminance clipped to [0, 1] per pixel (what an LDR display and
  LDR-FLIP can see), summed and divided by the element's own pixel count;
- **a prior** before its first traced frame (:func:`prior_per_pixel`), from the
  material under its pixels and its tagged effects: the specular reflectance
  times the mirror share of the reflection (the tracer's roughness blend) and
  the transmission, each times a typical contrast between the traced term and
  what raster puts there, plus a small constant for shadows.

:class:`BenefitModel` holds the estimates for a replay (one per
``FrameRenderer``): the first measurement replaces the prior, later ones are
averaged exponentially.  Plain numpy, no ``bpy``.
"""
from __future__ import annotations

import numpy as np

from . import shading

# Typical |traced - raster| of a fully replaced term (LDR): a traced reflection against the
# uniform environment colour raster puts there; a refraction bends the view of what raster
# shows straight through, which differs less.
REFLECTION_CONTRAST = 0.5
REFRACTION_CONTRAST = 0.2
# Prior per pixel of a shadow caster: shadow maps and rays mostly agree but at the edges.
SHADOW_PRIOR = 0.02
# Weight of a new measurement in the running estimate.
SMOOTHING = 0.3
# Rec. 709 luminance weights.
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])
# The largest benefit per pixel (a shadow caster's difference lands outside its own pixels).
MAX_BENEFIT = 1e3
# The prior reads every PRIOR_STEP-th covered pixel (an estimate: a quarter of the pixels is plenty).
PRIOR_STEP = 4


def _luminance(color):
    return np.clip(np.abs(np.asarray(color, dtype=np.float64)) @ LUMINANCE, 0.0, 1.0)


def prior_per_pixel(layers, n_elements, reflections, refractions, shadows) -> np.ndarray:
    """Expected difference per pixel of each element from the G-buffer samples on its pixels.

    ``layers`` are ``FrameRenderer._layer_samples`` (per layer: ``element`` index per
    covered pixel and its ``surface``); ``reflections``, ``refractions``, ``shadows``
    are the elements' effect flags.  0 for an element with no pixel.
    """
    from .tracer import reflection_blend

    total = np.zeros(n_elements)
    count = np.zeros(n_elements)
    flags = [np.asarray(flag, bool) for flag in (reflections, refractions, shadows)]
    for samples in layers.values():
        element = np.asarray(samples["element"])
        ours = np.flatnonzero((element >= 0) & (element < n_elements))[::PRIOR_STEP]
        if len(ours) == 0:
            continue
        element = element[ours]
        surface = samples["surface"]
        metallic = surface.metallic[ours].astype(np.float64)
        transmissive = surface.transmission[ours] * (1.0 - metallic)
        reflectance = surface.f0[ours] @ LUMINANCE
        expected = (flags[0][element] * reflectance * reflection_blend(surface.roughness[ours]) * REFLECTION_CONTRAST
                    + flags[1][element] * transmissive * REFRACTION_CONTRAST + flags[2][element] * SHADOW_PRIOR)
        total += np.bincount(element, weights=expected, minlength=n_elements)
        count += np.bincount(element, minlength=n_elements)
    return np.where(count > 0, total / np.maximum(count, 1), 0.0)


def copy_visibility(visibility):
    """The raster (shadow-map) visibility of every layer and light, before tracing replaces it."""
    return {layer: [terms.visibility.copy() for terms in per_light] for layer, per_light in visibility.items()}


def measure_differences(snapshot, layers, raster_visibility, visibility, reflection_radiance,
                        refraction_radiance, raster_behind, selected, element_bounds, materials) -> np.ndarray:
    """Summed per-pixel |traced - raster| (clipped linear luminance) attributable to each element.

    Arguments are the frame's own: the layer samples, the visibility before
    (``raster_visibility``, from :func:`copy_visibility`) and after tracing, the
    traced reflection and refraction radiance ``{layer: (pixel indices, radiance)}``,
    the raster colour those refracted pixels had behind the glass (``raster_behind``),
    the selection mask, each element's world bounds and the material table.
    """
    from .frame import shadow_region
    from .tracer import reflection_blend

    n = len(snapshot.elements)
    difference = np.zeros(n)
    world = np.asarray(snapshot.world_color, dtype=np.float64)
    for layer_name, (idx, radiance) in reflection_radiance.items():
        samples = layers[layer_name]
        surface = samples["surface"]
        part = _reflect_weight(surface, idx, world)
        blend = reflection_blend(surface.roughness[idx])[:, None]
        change = part * blend * (np.asarray(radiance, np.float64) - world)
        if layer_name == "transparent":
            change *= materials.alpha[samples["material"][idx]][:, None]
        np.add.at(difference, samples["element"][idx], _luminance(change))
    if "transparent" in refraction_radiance and raster_behind is not None:
        samples = layers["transparent"]
        idx, radiance = refraction_radiance["transparent"]
        surface = samples["surface"]
        metallic = surface.metallic[idx]
        transmissive = surface.transmission[idx] * (1.0 - metallic)
        cos_v = np.clip(shading.dot(surface.normal[idx], surface.view[idx]), 0.0, 1.0)
        fresnel_t = shading.fresnel_dielectric(cos_v, surface.ior[idx])
        alpha = materials.alpha[samples["material"][idx]]
        through = alpha * transmissive * (1.0 - fresnel_t)
        weight = through[:, None] * surface.albedo[idx] + (1.0 - alpha)[:, None]
        change = weight * (np.asarray(radiance, np.float64) - np.asarray(raster_behind, np.float64))
        np.add.at(difference, samples["element"][idx], _luminance(change))
    casters = [index for index in np.flatnonzero(selected)
               if snapshot.elements[index].shadows and element_bounds[index] is not None]
    if casters:
        for layer_name, per_light in visibility.items():
            samples = layers[layer_name]
            surface = samples["surface"]
            for light_index, terms in enumerate(per_light):
                before = raster_visibility[layer_name][light_index]
                changed = np.flatnonzero(np.abs(terms.visibility - before) > 1e-6)
                if len(changed) == 0:
                    continue
                pixels = terms.active[changed]
                light_color = shading.brdf_cosine(surface.subset(pixels), terms.direction[changed]) \
                    * terms.irradiance[changed]
                change = _luminance(light_color * (terms.visibility[changed] - before[changed])[:, None])
                points = samples["world"][pixels]
                light = snapshot.lights[light_index]
                owners = np.stack([shadow_region(light, element_bounds[caster], points) for caster in casters])
                shares = owners.sum(axis=0)
                weights = np.where(shares > 0, change / np.maximum(shares, 1), 0.0)
                difference[casters] += owners.astype(np.float64) @ weights
    return difference


def _reflect_weight(surface, idx, world):
    """The weight of the reflected term in the composite (environment Fresnel for the
    opaque part, dielectric Fresnel for the transmissive part), at the pixels ``idx``."""
    f0 = surface.f0[idx]
    fresnel = shading.environment_fresnel(f0, surface.n_dot_v[idx], surface.roughness[idx])
    transmissive = surface.transmission[idx] * (1.0 - surface.metallic[idx])
    cos_v = np.clip(shading.dot(surface.normal[idx], surface.view[idx]), 0.0, 1.0)
    fresnel_t = shading.fresnel_dielectric(cos_v, surface.ior[idx])
    return fresnel * (1.0 - transmissive)[:, None] + (transmissive * fresnel_t)[:, None]


class BenefitModel:
    """Per element (by name): the running estimate of its traced-vs-raster difference per pixel."""

    def __init__(self, smoothing: float = SMOOTHING):
        self.smoothing = float(smoothing)
        self.estimates: dict[str, float] = {}
        self.observations: dict[str, int] = {}

    def benefit(self, names, prior) -> np.ndarray:
        """Per element: the learned estimate once measured, else ``prior``."""
        prior = np.nan_to_num(np.asarray(prior, dtype=np.float64), nan=0.0, posinf=MAX_BENEFIT, neginf=0.0)
        learned = self.estimates.get
        values = np.fromiter((learned(name, -1.0) for name in names), dtype=np.float64, count=len(names))
        return np.clip(np.where(values >= 0, values, prior), 0.0, MAX_BENEFIT)

    def observe(self, names, traced, difference, area_px) -> None:
        """Learn from one frame: ``difference`` summed per element (``measure_differences``),
        for the elements ``traced`` with at least one pixel."""
        traced = np.asarray(traced, bool) & (np.asarray(area_px) > 0)
        per_pixel = np.asarray(difference, np.float64) / np.maximum(np.asarray(area_px, np.float64), 1.0)
        per_pixel = np.clip(np.nan_to_num(per_pixel, nan=0.0, posinf=MAX_BENEFIT), 0.0, MAX_BENEFIT)
        for index in np.flatnonzero(traced).tolist():
            name = names[index]
            value = float(per_pixel[index])
            if name in self.estimates:
                self.estimates[name] += self.smoothing * (value - self.estimates[name])
            else:
                self.estimates[name] = value
            self.observations[name] = self.observations.get(name, 0) + 1
