"""Rays of the BENEFIT selection's (element, effect) items: per pixel of each element, per item,
and the effect flags as an (n, 3) array in ``EFFECTS`` order (shadows, reflections, refractions)."""
from __future__ import annotations

import numpy as np


def effect_rays_per_pixel(snapshot, area_px, footprint) -> np.ndarray:
    """(n, 3) rays one pixel of each element costs per effect (shadows, reflections, refractions),
    whether or not it is tagged for it (input of the measured cost model)."""
    n_lights = len(snapshot.lights)
    shadows = np.asarray(footprint, np.float64) / np.maximum(np.asarray(area_px, np.float64), 1.0)
    return np.stack([shadows, np.full(len(shadows), 1.0 + n_lights),  # the reflection ray and its hit's shadow rays
                     np.full(len(shadows), 2.0 + n_lights)], axis=1)  # in, out, and the hit's shadow rays


def expected_rays(area_px, effect_rays) -> np.ndarray:
    """(n, 3) rays each (element, effect) item is expected to cast (before its learned ratio)."""
    return np.asarray(area_px, np.float64)[:, None] * np.asarray(effect_rays, np.float64)


def flags_array(flags) -> np.ndarray:
    return np.stack([flags["shadows"], flags["reflections"], flags["refractions"]], axis=1).astype(np.float64)
