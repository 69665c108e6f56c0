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
    """(n, 3) summed per-pixel change of each traced item (``chosen`` (n, 3) the traced items);
    only the traced pixels are looked at (``benefit.owned_change``)."""
    n = len(snapshot.elements)
    result = np.zeros((n, len(EFFECTS)))
    values = np.asarray(change).reshape(-1, change.shape[-1])[:, 0]
    refraction = traced.refraction[0] if traced.refraction is not None else None
    reflections = [("opaque", traced.reflection["opaque"][0])] if "opaque" in traced.reflection else []
    if "transparent" in traced.reflection:  # where the glass was refracted too, the refraction's pixel
        where = traced.reflection["transparent"][0]
        reflections.append(("transparent", where if refraction is None else
                            np.setdiff1d(where, refraction, assume_unique=False)))
    result[:, 1] = benefit.owned_change(layers, reflections, values, n)
    result[:, 2] = benefit.owned_change(layers, [("transparent", refraction)], values, n)
    result[:, 0] = benefit.shadow_differences(snapshot, layers, change, traced, np.asarray(chosen)[:, 0],
                                              element_bounds)
    return result * np.asarray(chosen, bool)
