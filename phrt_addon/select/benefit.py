"""Expected benefit of ray tracing an element: the error-aware relevance (``relevance = 'error'``).

The paper's relevance knows where an element is (V = A * P / D) but not how
wrong its raster version looks: a mirror facing a bright wall and a matte cube
of the same size get the same V, while only the mirror changes when traced.
This module keeps, per element, a running estimate of how much its traced
image differs from its raster image, per pixel of the element:

- **measured** on frames where the element was traced (:func:`measure_differences`):
  the GPU composite evaluates every traced pixel twice, with the traced terms
  and with the raster ones (environment reflection, straight-through
  transparency, shadow-map visibility), and writes the difference beside the
  image; reflections and refractions are charged to the element traced at the
  pixel, shadow changes to the selected casters whose shadow region holds the
  receiving pixel.  Differences are in linear luminance clipped to [0, 1] per
  pixel (what an LDR display and LDR-FLIP can see), summed and divided by the
  element's own pixel count;
- **a prior** before its first traced frame (:func:`prior_per_pixel`), from the
  materials under its pixels and its tagged effects: the specular reflectance
  times the mirror share of the reflection (the tracer's roughness blend) and
  the transmission, each times a typical contrast between the traced term and
  what raster puts there, plus a small constant for shadows.

:class:`BenefitModel` holds the estimates for a replay (one per
``FrameRenderer``): the first measurement replaces the prior, later ones are
averaged exponentially.  Plain numpy, no ``bpy``.
"""
from __future__ import annotations

import numpy as np

from ..scene import shading

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


def prior_per_pixel(layers, n_elements, reflections, refractions, shadows, materials) -> np.ndarray:
    """Expected difference per pixel of each element from the materials under its pixels.

    ``layers`` are the frame's read-back ``frame.LayerPixels`` (per layer: ``element``,
    ``material`` and ``roughness`` per covered pixel), or None when nothing was read back
    (then no element is visible and every prior is 0); ``reflections``, ``refractions``,
    ``shadows`` are the elements' effect flags; ``materials`` the ``shading.MaterialTable``.
    """
    return _prior(layers, n_elements, (reflections, refractions, shadows), materials, apart=False)[:, 0]


def prior_terms(layers, n_elements, reflections, refractions, shadows, materials) -> np.ndarray:
    """(n, 3): :func:`prior_per_pixel`'s reflection, refraction and shadow terms apart: the
    BENEFIT selection's per-item priors, the layers' pixels gathered once for all three."""
    return _prior(layers, n_elements, (reflections, refractions, shadows), materials, apart=True)


def _prior(layers, n_elements, flags, materials, apart: bool) -> np.ndarray:
    """(n, 3) the terms per element (``apart``) or (n, 1) their sum, averaged over a sample of
    each element's pixels."""
    from ..trace.tracer import reflection_blend

    total = np.zeros((n_elements, 3 if apart else 1))
    count = np.zeros(n_elements)
    if layers is None:
        return total
    flags = [np.asarray(flag, bool) for flag in flags]
    f0 = shading.specular_f0(materials.base_color, materials.metallic, materials.ior) @ LUMINANCE
    transmissive = materials.transmission * (1.0 - materials.metallic)
    for pixels in layers.values():
        element = np.asarray(pixels.element)
        ours = np.flatnonzero((element >= 0) & (element < n_elements))[::PRIOR_STEP]
        if len(ours) == 0:
            continue
        element = element[ours]
        material = pixels.material[ours]
        terms = (flags[0][element] * f0[material] * reflection_blend(pixels.roughness[ours]) * REFLECTION_CONTRAST,
                 flags[1][element] * transmissive[material] * REFRACTION_CONTRAST,
                 flags[2][element] * SHADOW_PRIOR)
        for column, expected in enumerate(terms if apart else (terms[0] + terms[1] + terms[2],)):
            total[:, column] += np.bincount(element, weights=expected, minlength=n_elements)
        count += np.bincount(element, minlength=n_elements)
    return np.where(count[:, None] > 0, total / np.maximum(count, 1)[:, None], 0.0)


def elements_at(pixels, where) -> np.ndarray:
    """The element of each frame pixel ``where`` in a layer's ``pixels`` (its ``flat`` ascending),
    -1 where the layer has none."""
    flat = pixels.flat
    if not len(flat):
        return np.full(len(where), -1, np.int64)
    position = np.minimum(np.searchsorted(flat, where), len(flat) - 1)
    return np.where(flat[position] == where, np.asarray(pixels.element, np.int64)[position], -1)


def owned_change(layers, parts, values, n) -> np.ndarray:
    """(n,) per element, the summed ``values`` (one per frame pixel) of the traced pixels ``parts``
    ((layer name, flat pixels) in order; a pixel in several parts belongs to the last one's
    element there).  Only the traced pixels are looked at, not frame-sized maps of owners (1.5 ms
    -> 0.4 a measured frame, atrium path1 at 320x240).  Each part's pixels are distinct and each
    layer's ``flat`` ascending (``LayerPixels``: from ``flatnonzero``; traced pixels are some of
    them)."""
    parts = [(name, np.asarray(where, np.int64)) for name, where in parts if where is not None and len(where)]
    if not parts:
        return np.zeros(n)
    where = np.concatenate([part for _, part in parts])
    owner = np.concatenate([elements_at(layers[name], part) for name, part in parts])
    if len(parts) > 1:  # the last part's element owns a pixel traced in several
        _, last = np.unique(where[::-1], return_index=True)
        keep = len(where) - 1 - last
        where, owner = where[keep], owner[keep]
    mine = (owner >= 0) & (owner < n)
    return np.bincount(owner[mine], weights=values[where[mine]], minlength=n)[:n]


def measure_differences(snapshot, layers, change, traced, selected, element_bounds) -> np.ndarray:
    """Summed per-pixel |traced - raster| (clipped linear luminance) attributable to each element.

    ``change`` is the GPU's measurement (``RasterFrame.traced_change``): x, what the traced
    reflections and refractions changed at their own pixels, charged to the element traced
    there (the transparent layer's where both were); y, what the traced shadows changed on
    whatever surface receives them, shared between the selected casters whose shadow region
    holds the pixel.  ``traced`` is the frame's ``frame.TracedTerms``.
    """
    n = len(snapshot.elements)
    flat_change = np.asarray(change).reshape(-1, change.shape[-1])  # a view: float64 where summed
    parts = [(name, traced.reflection[name][0]) for name in ("opaque", "transparent") if name in traced.reflection]
    if traced.refraction is not None:
        parts.append(("transparent", traced.refraction[0]))
    difference = owned_change(layers, parts, flat_change[:, 0], n)
    return difference + shadow_differences(snapshot, layers, change, traced, selected, element_bounds)


def shadow_differences(snapshot, layers, change, traced, casting, element_bounds) -> np.ndarray:
    """Per element: the summed change the traced shadows made (``change``'s y) on the pixels in its
    shadow region, shared between the ``casting`` elements (tagged for shadows) whose region holds
    the pixel; each pixel's change (all lights) counted once."""
    from ..trace.shadow_region import ShadowRegionIndex

    n = len(snapshot.elements)
    difference = np.zeros(n)
    flat_change = np.asarray(change).reshape(-1, change.shape[-1])  # a view: float64 where divided
    casters = [index for index in np.flatnonzero(casting)
               if snapshot.elements[index].shadows and element_bounds[index] is not None]
    if casters:
        shadow_change = flat_change[:, 1]
        charged = np.zeros(len(flat_change), bool)
        for key, (where, _) in traced.shadow_visibility.items():
            layer_name, light_index = key
            where = where[(shadow_change[where] > 0) & ~charged[where]]
            if len(where) == 0:
                continue
            charged[where] = True  # a pixel's change (all lights) is shared once
            owners = _owners_from_trace(traced.shadow_owners.get(key), where, casters, len(flat_change))
            if owners is None:  # regions not kept by the trace stage: built again here
                pixels = layers[layer_name]
                position = np.full((len(flat_change), 3), np.nan)
                position[pixels.flat] = pixels.world()
                index = ShadowRegionIndex(snapshot.lights[light_index], position[where])
                owners = np.stack([index.region(element_bounds[caster]) for caster in casters])
            shares = owners.sum(axis=0)
            weights = np.where(shares > 0, shadow_change[where] / np.maximum(shares, 1), 0.0)
            difference[casters] += owners.astype(np.float64) @ weights
    return difference


def _owners_from_trace(kept, where, casters, n_pixels):
    """(casters, len(where)) bool: which casters' regions hold each pixel of ``where``, from the
    regions the trace stage built (``TracedTerms.shadow_owners``); None without them."""
    if kept is None:
        return None
    flat, layer_index, traced_casters, regions = kept
    row_of = {caster: row for row, caster in enumerate(traced_casters)}
    if any(caster not in row_of for caster in casters):
        return None
    position = np.full(n_pixels, -1, np.int64)
    position[flat] = np.arange(len(flat))
    at = position[where]
    found = at >= 0
    in_layer = layer_index[at[found]]
    owners = np.zeros((len(casters), len(where)), bool)
    for row, caster in enumerate(casters):
        owners[row, found] = regions[row_of[caster]][in_layer]
    return owners


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
