"""G-buffer: what the raster pass leaves for shading, selection and tracing.

Two layers, both (h, w) images with row 0 at the bottom (Blender's pixel order):
``opaque`` holds the nearest opaque surface, ``transparent`` the nearest
transparent surface in front of it (glass, water, alpha-blended cards).  The
raster pass fills them on the GPU (``engine/raster.py``); tests may build them
by hand.

Positions are stored relative to ``origin`` (the camera position, float64) so
that float32 keeps its precision at huge world coordinates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class GBufferLayer:
    covered: np.ndarray  # (h, w) bool: a surface was drawn here
    position: np.ndarray  # (h, w, 3) float32, world position minus GBuffer.origin
    normal: np.ndarray  # (h, w, 3) float32 unit shading normal, facing the camera
    roughness: np.ndarray  # (h, w) float32
    albedo: np.ndarray  # (h, w, 3) float32 base colour (texture applied)
    metallic: np.ndarray  # (h, w) float32
    material: np.ndarray  # (h, w) int32 material index, -1 where not covered
    element: np.ndarray  # (h, w) int32 element index, -1 where none

    @classmethod
    def empty(cls, width: int, height: int) -> "GBufferLayer":
        return cls(
            covered=np.zeros((height, width), bool),
            position=np.zeros((height, width, 3), np.float32),
            normal=np.zeros((height, width, 3), np.float32),
            roughness=np.zeros((height, width), np.float32),
            albedo=np.zeros((height, width, 3), np.float32),
            metallic=np.zeros((height, width), np.float32),
            material=np.full((height, width), -1, np.int32),
            element=np.full((height, width), -1, np.int32),
        )


@dataclass
class GBuffer:
    opaque: GBufferLayer
    transparent: GBufferLayer
    origin: np.ndarray  # (3,) float64 world position the layers' positions are relative to
    view_depth: np.ndarray  # (h, w) float32 distance along the camera axis of the front surface; inf = background

    @property
    def height(self) -> int:
        return self.opaque.covered.shape[0]

    @property
    def width(self) -> int:
        return self.opaque.covered.shape[1]

    def front_element(self) -> np.ndarray:
        """Element index of the front-most surface of each pixel (transparent over opaque)."""
        return np.where(self.transparent.covered, self.transparent.element, self.opaque.element)

    def front_normal(self) -> np.ndarray:
        return np.where(self.transparent.covered[..., None], self.transparent.normal, self.opaque.normal)


def element_pixel_stats(element_image: np.ndarray, n_elements: int, view_depth: np.ndarray):
    """Per element, from the element-id image: pixel count, pixel centroid in NDC
    (-1..1) and median view depth of its pixels.

    Whole-array numpy (bincount); elements with no pixels get count 0, centroid
    (0, 0) and depth inf.  This is the exact "area in the view plane" of the paper's
    A, measured rather than estimated from bounds."""
    height, width = element_image.shape
    flat = element_image.ravel()
    mask = flat >= 0
    ids = flat[mask]
    counts = np.bincount(ids, minlength=n_elements)[:n_elements].astype(np.int64)
    ys, xs = np.divmod(np.flatnonzero(mask), width)
    ndc_x = (xs + 0.5) / width * 2.0 - 1.0
    ndc_y = (ys + 0.5) / height * 2.0 - 1.0
    safe = np.maximum(counts, 1)
    centre = np.zeros((n_elements, 2))
    centre[:, 0] = np.bincount(ids, weights=ndc_x, minlength=n_elements)[:n_elements] / safe
    centre[:, 1] = np.bincount(ids, weights=ndc_y, minlength=n_elements)[:n_elements] / safe
    # Mean depth (bincount) rather than the median: O(n) and stable for convex-ish elements.
    depth_values = view_depth.ravel()[mask].astype(np.float64)
    finite = np.isfinite(depth_values)
    depth_sum = np.bincount(ids[finite], weights=depth_values[finite], minlength=n_elements)[:n_elements]
    depth_count = np.bincount(ids[finite], minlength=n_elements)[:n_elements]
    depth = np.where(depth_count > 0, depth_sum / np.maximum(depth_count, 1), np.inf)
    return counts, centre, depth
