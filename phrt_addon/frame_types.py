"""The data that flows between the stages of a frame (docs/DESIGN.md, "Data flow").

- ``RasterFrame``: the raster half as the core sees it (``engine/gpu/frame.GPUFrame`` on the
  GPU, ``raster.reference_raster.ReferenceRaster`` in numpy);
- ``LayerPixels``: the covered pixels of one read-back G-buffer layer, for the rays;
- ``TracedTerms``: what the trace stage computed, which the lighting and composite use
  in place of the raster terms;
- ``FramePasses`` and ``FrameResult``: what a frame gives back.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from .gather import compress_rows, take_rows
from .scene import shading
from .raster.gbuffer import GBuffer
from .raster.normals import geometric_normals


def rows_of(array: np.ndarray, index) -> np.ndarray:
    """``array[index]`` along the first axis: ``np.take`` / ``np.compress`` for an index array
    (of (n, 3) rows several times faster than numpy's fancy indexing; ``gather.take_rows``: not
    from a strided view, which they copy whole first); a mask of another length is an error, as
    it is for ``array[mask]``."""
    if isinstance(index, slice):
        return array[index]
    index = np.asarray(index)
    if index.size == 0 and index.dtype != bool:
        index = index.astype(np.intp)  # [] is float64 to numpy
    if index.dtype == bool:
        if index.shape != array.shape[:1]:
            raise IndexError(f"a mask of {index.shape} over {array.shape[0]} rows")
        return compress_rows(index, array)
    return take_rows(array, index)


class RasterFrame(Protocol):
    width: int
    height: int
    raster_ms: float  # G-buffer drawn and read back, shadow maps included
    setup_ms: float  # the one-time part of raster_ms (compiles, uploads, new shadow maps)
    front_element: np.ndarray  # (h, w) int, -1 where no element
    view_depth: np.ndarray  # (h, w) float32 distance along the view axis; inf = background
    front_normal: np.ndarray  # (h, w, 3) float32
    stats: dict

    def gbuffer(self, rect=None) -> GBuffer:
        """Both layers read back; with ``rect`` (x, y, w, h, row 0 at the bottom) at least the
        pixels inside it, the others possibly cleared (not covered, no element)."""

    def shade(self, traced: "TracedTerms | None", measure_change: bool = False) -> np.ndarray | None: ...

    def traced_change(self) -> np.ndarray:
        """(h, w, 4) after ``shade(..., measure_change=True)``: per pixel, the luminance (clipped
        to [0, 1]) of what the traced reflections and refractions (x) and the traced shadows (y)
        changed against the raster image."""


@dataclass
class TracedTerms:
    """What the trace stage computed, by flat pixel index (row 0 at the bottom)."""

    # (layer, light index) -> (pixels, lit fraction): replaces the shadow map there
    shadow_visibility: dict = field(default_factory=dict)
    # layer -> (pixels, (n, 3) radiance reflected towards the viewer, blended by roughness)
    reflection: dict = field(default_factory=dict)
    # (pixels, (n, 3) radiance arriving through the transparent layer), or None
    refraction: tuple | None = None
    # (layer, light index) -> (pixels, their indices in the layer, caster element indices, per
    # caster its region over the layer's pixels): who a traced shadow change belongs to
    shadow_owners: dict = field(default_factory=dict)


@dataclass
class FramePasses:
    combined: np.ndarray | None  # (h,w,4) float32, linear, alpha 1; None if left on the GPU
    depth: np.ndarray  # (h,w) float32 view-axis distance; 1e10 where background
    normal: np.ndarray  # (h,w,3) float32
    selected: np.ndarray  # (h,w) float32, 1 where the front element was ray traced
    candidate: np.ndarray  # (h,w) float32, 1 on candidate elements' pixels
    element: np.ndarray | None = None  # (h,w) float32, front element index + 1 (0: none)
    rate: np.ndarray | None = None  # (h,w) float32, rate of the traced terms (1, 0.5, 0.25; 0: raster)
    effect_rate: dict | None = None  # effect name -> (h,w) float32, the same per effect (not a pass)


@dataclass
class FrameResult:
    passes: FramePasses
    stats: dict
    selection: object
    selection_rows: list
    problems: list = field(default_factory=list)


class LayerPixels:
    """The covered pixels of one read-back G-buffer layer; per-pixel terms are computed only
    for the subsets that get rays.  ``elements`` (optional, (n + 1,) bool over element ids, the
    last for "no element"): only the pixels of those elements (a frame that traces reflections
    and refractions only casts rays from its chosen elements' own pixels; gathering every
    covered pixel cost 1.5 ms a layer at 320x240).

    The per-pixel attributes (``position``, ``element``, ``material``, ``roughness``) are
    gathered from the layer's images on first use, and the methods given an ``index`` gather
    only those pixels until then: a frame tracing a few shadows reads the positions of the
    pixels its casters may reach, not of the whole layer (3.2 ms a frame at 320x240)."""

    def __init__(self, layer, origin, camera, materials: shading.MaterialTable, elements=None, rect=None):
        self.layer = layer
        height, width = layer.covered.shape
        x, y, w, h = (0, 0, width, height) if rect is None else rect
        # ``rect`` (x, y, w, h): only pixels inside it are gathered (the read-back's rectangle).
        covered = layer.covered[y:y + h, x:x + w]
        if elements is not None:
            keep = np.asarray(elements, bool)
            ids = layer.element[y:y + h, x:x + w]
            covered = covered & keep[np.where((ids >= 0) & (ids < len(keep) - 1), ids, len(keep) - 1)]
        local = np.flatnonzero(covered)
        # Rows of the rectangle to rows of the frame (flat indices stay ascending).
        self.flat = local if rect is None else (local // w + y) * width + local % w + x
        self.origin = np.asarray(origin, np.float64)
        self.camera = camera
        self.materials = materials
        self._cache = {}

    def _gathered(self, name: str, index=slice(None)) -> np.ndarray:
        """The layer's image ``name`` at the pixels ``index`` (of ``flat``): from the whole
        gather once made, else straight from the image; an index over a quarter of the layer
        makes the whole gather (kept)."""
        whole = self._cache.get(name)
        if whole is not None:
            return rows_of(whole, index)
        image = getattr(self.layer, name)
        values = image.reshape(image.shape[0] * image.shape[1], -1) if image.ndim == 3 else image.reshape(-1)
        rows = None if isinstance(index, slice) and index == slice(None) else self.flat[index]
        if rows is None or 4 * len(rows) > len(self.flat):  # much of the layer: gathered whole, kept
            self._cache[name] = whole = take_rows(values, self.flat)
            return rows_of(whole, index)
        return take_rows(values, rows)  # rows of (n, 3): np.take where it is faster than values[rows]

    @property
    def position(self) -> np.ndarray:
        """(n, 3) float32 camera-relative positions."""
        return self._gathered("position")

    @property
    def element(self) -> np.ndarray:
        return self._gathered("element")

    @property
    def material(self) -> np.ndarray:
        if "material_index" not in self._cache:
            self._cache["material_index"] = np.clip(self._gathered("material"), 0, len(self.materials.ior) - 1)
        return self._cache["material_index"]

    @property
    def roughness(self) -> np.ndarray:
        return self._gathered("roughness")

    def __len__(self):
        return len(self.flat)

    def world(self, index=slice(None)) -> np.ndarray:
        """float64 world positions of the pixels ``index``.  Once the calls in parts have asked for
        more than half the layer (a frame's shadow regions, light after light), the whole layer's
        are made once and kept: the lights after that share them."""
        whole = self._cache.get("world")
        if whole is not None:
            return rows_of(whole, index)
        if isinstance(index, slice) and index == slice(None):
            whole = self._cache["world"] = self._gathered("position").astype(np.float64) + self.origin
            return whole
        asked = self._cache["world_asked"] = self._cache.get("world_asked", 0) + len(self.flat[index])
        if 2 * asked > len(self.flat):
            return rows_of(self.world(), index)
        return self._gathered("position", index).astype(np.float64) + self.origin

    def view_directions(self, index=slice(None)) -> np.ndarray:
        """Unit directions from the camera (perspective) or the camera axis (orthographic)."""
        position = self._gathered("position", index)
        if self.camera.ortho:
            return np.broadcast_to(self.camera.forward.astype(np.float32), position.shape).copy()
        return shading.normalize(position)

    def normals(self, index=slice(None), view_directions=None) -> np.ndarray:
        """Unit shading normals facing the viewer (flipped where interpolation turned them away)."""
        normal = shading.normalize(self._gathered("normal", index))
        if view_directions is None:
            view_directions = self.view_directions(index)
        back = shading.dot(normal, view_directions) > 0
        normal[back] *= -1.0
        return normal

    def geometric_normals(self, index, view_directions) -> np.ndarray:
        """Face normals facing the camera (where secondary rays leave from: rules of tracer.py).
        Each pixel's is computed once a frame and kept: a pixel in several lights' shadow
        regions, or also reflecting, is not computed again (an arcade frame of five shadow lights
        and reflections, 86k rays: the trace stage 98.9 -> 93.2 ms).  ``view_directions``: the
        camera's (``view_directions(index)``), the same for a pixel on every call of the frame."""
        index = np.arange(len(self.flat))[index] if isinstance(index, slice) else np.asarray(index)
        index = np.flatnonzero(index) if index.dtype == bool else index.astype(np.intp, copy=False)
        view_directions = np.broadcast_to(np.asarray(view_directions, np.float64).reshape(-1, 3), (len(index), 3))
        kept = self._cache.get("geometric_normals")
        if kept is None:
            kept = self._cache["geometric_normals"] = (np.zeros((len(self.flat), 3)), np.zeros(len(self.flat), bool))
        values, done = kept
        todo = ~done[index]
        if todo.any():
            new, first = np.unique(index[todo], return_index=True)  # a pixel asked twice: computed once
            first = np.flatnonzero(todo)[first]
            values[new] = geometric_normals(self.layer, self.flat[new], rows_of(view_directions, first))
            done[new] = True
        return take_rows(values, index)

    def camera_distance(self, index=slice(None)) -> np.ndarray:
        """Distance from the camera: the size of the points' float32 error, which secondary-ray
        offsets must exceed (telephoto views)."""
        position = self._gathered("position", index)
        return np.sqrt(shading.dot(position, position))
