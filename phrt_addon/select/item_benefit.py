"""Per (element, effect) item: the pixels it changes, its prior and its measured difference.

The ``BENEFIT`` selection's inputs (``benefit_selection.py``), in ``EFFECTS`` order
(shadows, reflections, refractions), as (n, 3) arrays:

- :func:`item_pixels`: reflections and refractions change the element's own pixels,
  shadows the receivers' pixels in the caster's shadow footprint;
- :func:`priors`: the error-aware relevance's material prior (``benefit.prior_per_pixel``),
  one effect at a time;
- :func:`measure`: what the traced terms changed in the frame (the GPU's
  ``traced_change``: x at reflection and refraction pixels, y on shadow receivers), charged
  to the item that changed it: a reflection pixel to its element's reflection, a refraction
  pixel to its element's refraction (the transparent layer's pixel where both were traced
  goes to the refraction, which decides most of what is seen through glass), a shadow
  receiver's change to the selected casters whose region holds it (``benefit.measure_differences``).
"""
from __future__ import annotations

import numpy as np

from . import benefit
from ..schema import EFFECTS


def item_pixels(area_px, footprint) -> np.ndarray:
    area = np.asarray(area_px, np.float64)
    return np.stack([np.asarray(footprint, np.float64), area, area], axis=1)


def priors(layers, n_elements, flags, materials) -> np.ndarray:
    """(n, 3) expected difference per changed pixel of each item, from the materials (columns in
    ``EFFECTS`` order: shadows, reflections, refractions)."""
    terms = benefit.prior_terms(layers, n_elements, flags["reflections"], flags["refractions"], flags["shadows"],
                                materials)  # reflections, refractions, shadows
    return terms[:, [2, 0, 1]]


def measure(snapshot, layers, change, traced, chosen, element_bounds) -> np.ndarray:
    """(n, 3) summed per-pixel change of each traced item (``chosen`` (n, 3) the traced items)."""
    n = len(snapshot.elements)
    result = np.zeros((n, len(EFFECTS)))
    flat_change = np.asarray(change).reshape(-1, change.shape[-1])  # float64 only where summed (bincount)
    for effect, column in (("reflections", 1), ("refractions", 2)):
        owner = np.full(len(flat_change), -1, np.int64)
        for layer_name in ("opaque", "transparent"):
            pixels = layers[layer_name]
            element_at = np.full(len(flat_change), -1, np.int64)
            element_at[pixels.flat] = pixels.element
            if effect == "reflections" and layer_name in traced.reflection:
                where = traced.reflection[layer_name][0]
                if layer_name == "transparent" and traced.refraction is not None:
                    where = np.setdiff1d(where, traced.refraction[0], assume_unique=False)
                owner[where] = element_at[where]
            if effect == "refractions" and layer_name == "transparent" and traced.refraction is not None:
                where = traced.refraction[0]
                owner[where] = element_at[where]
        mine = np.flatnonzero((owner >= 0) & (owner < n))
        result[:, column] = np.bincount(owner[mine], weights=flat_change[mine, 0], minlength=n)[:n]
    result[:, 0] = benefit.shadow_differences(snapshot, layers, change, traced, np.asarray(chosen)[:, 0],
                                              element_bounds)
    return result * np.asarray(chosen, bool)
