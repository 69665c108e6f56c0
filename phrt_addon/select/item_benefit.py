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


def elements_at(pixels, where) -> np.ndarray:
    """The element of each frame pixel ``where`` in a layer's ``pixels`` (its ``flat`` ascending),
    -1 where the layer has none."""
    flat = pixels.flat
    position = np.minimum(np.searchsorted(flat, where), max(len(flat) - 1, 0))
    if not len(flat):
        return np.full(len(where), -1, np.int64)
    return np.where(flat[position] == where, np.asarray(pixels.element, np.int64)[position], -1)


def measure(snapshot, layers, change, traced, chosen, element_bounds) -> np.ndarray:
    """(n, 3) summed per-pixel change of each traced item (``chosen`` (n, 3) the traced items).
    Only the traced pixels are looked at (not frame-sized maps of owners: 1.3 -> 0.3 ms a measured
    frame at 320x240); where both layers traced a pixel, the transparent layer's element owns it."""
    n = len(snapshot.elements)
    result = np.zeros((n, len(EFFECTS)))
    flat_change = np.asarray(change).reshape(-1, change.shape[-1])  # float64 only where summed (bincount)
    for effect, column in (("reflections", 1), ("refractions", 2)):
        where_parts, owner_parts = [], []
        for layer_name in ("opaque", "transparent"):
            where = None
            if effect == "reflections" and layer_name in traced.reflection:
                where = traced.reflection[layer_name][0]
                if layer_name == "transparent" and traced.refraction is not None:
                    where = np.setdiff1d(where, traced.refraction[0], assume_unique=False)
            if effect == "refractions" and layer_name == "transparent" and traced.refraction is not None:
                where = traced.refraction[0]
            if where is not None and len(where):
                where = np.asarray(where, np.int64)
                where_parts.append(where)
                owner_parts.append(elements_at(layers[layer_name], where))
        if not where_parts:
            continue
        where, owner = np.concatenate(where_parts), np.concatenate(owner_parts)
        if len(where_parts) > 1:  # a pixel traced in both layers: the later (transparent) layer's
            _, last = np.unique(where[::-1], return_index=True)
            keep = len(where) - 1 - last
            where, owner = where[keep], owner[keep]
        mine = (owner >= 0) & (owner < n)
        result[:, column] = np.bincount(owner[mine], weights=flat_change[where[mine], 0], minlength=n)[:n]
    result[:, 0] = benefit.shadow_differences(snapshot, layers, change, traced, np.asarray(chosen)[:, 0],
                                              element_bounds)
    return result * np.asarray(chosen, bool)
