"""What guides the edge-aware reconstruction of reduced-rate effects (``rates.py``): per pixel,
depth, unit normal and an id that pixels of different elements never share, from flat arrays
(``Guide.of``) or a G-buffer layer (``layer_guide``), as padded float32 / int64 images of a
window."""
from __future__ import annotations

import numpy as np

NO_ID = np.iinfo(np.int64).min


PAD = 2  # the padding of a guide's images: every 5x5 offset of an image pixel is an index


class Guide:
    """Per-pixel guide of an (h, w) image: ``depth`` (inf where nothing), ``normal`` (3), and
    ``element`` (int id: pixels of different ids never mix).  ``Guide.of`` takes flat (h * w)
    arrays; ``layer_guide`` reads a G-buffer layer.  The filter reads ``padded``: the guide as
    flat float32 / int64 images padded by ``PAD`` pixels (no depth, no id, no normal there),
    computed once and shared by every reconstruction of the frame's layer (the lights' shadows
    and the reflections)."""

    def __init__(self, depth, normal, element):
        self.depth = np.asarray(depth, np.float64).ravel()
        self.normal = np.asarray(normal, np.float64).reshape(-1, 3)
        self.element = np.asarray(element).ravel().astype(np.int64)
        self._padded = {}

    @classmethod
    def of(cls, depth, normal, element) -> "Guide":
        return cls(depth, normal, element)

    @property
    def size(self) -> int:
        return len(self.depth)

    def _images(self, width: int, rows: slice, cols: slice):
        """(depth, [x, y, z] unit normal, id) images of the window ``rows`` x ``cols``."""
        height = self.size // width

        def window(flat_image):
            return flat_image.reshape(height, width)[rows, cols]

        x, y, z = (np.asarray(window(self.normal[:, axis]), np.float32) for axis in range(3))
        with np.errstate(invalid="ignore", over="ignore"):
            length = np.sqrt(x * x + y * y + z * z)
        usable = np.isfinite(length) & (length > 1e-12)
        safe = np.where(usable, length, np.float32(1.0))
        return window(self.depth), [np.where(usable, c / safe, np.float32(0.0)) for c in (x, y, z)], window(self.element)

    def padded(self, width: int, rows: slice, cols: slice):
        """(depth, [x, y, z] of the unit normal, id) of the window ``rows`` x ``cols`` as flat
        images padded by ``PAD`` on every side: float32 depth (inf where nothing or not finite,
        and in the padding), float32 normal (0 where unusable), int64 id (NO_ID in the padding).
        The whole image's is kept for the frame (the lights' frame-wide shadows of one layer
        share it); a smaller window's is not (lights of their own rectangles would pile up)."""
        key = (width, rows.start, rows.stop, cols.start, cols.stop)
        if key not in self._padded:
            depth, normal, ids = self._images(width, rows, cols)
            with np.errstate(invalid="ignore", over="ignore"):
                depth = np.where(np.isfinite(depth), depth, np.inf).astype(np.float32)
            pad = [(PAD, PAD), (PAD, PAD)]
            # A non-finite normal (normalize() of a zero one on the GPU) weighs nothing, as none.
            normal = [np.asarray(c, np.float32) for c in normal]
            usable = np.isfinite(normal[0]) & np.isfinite(normal[1]) & np.isfinite(normal[2])
            padded = (np.pad(depth, pad, constant_values=np.inf).ravel(),
                      [np.pad(np.where(usable, c, np.float32(0.0)), pad).ravel() for c in normal],
                      np.pad(np.asarray(ids, np.int64), pad, constant_values=NO_ID).ravel())
            if (rows.stop - rows.start) * (cols.stop - cols.start) < self.size:
                return padded
            self._padded[key] = padded
        return self._padded[key]


class _LayerGuide(Guide):
    """The guide of a G-buffer layer (see ``layer_guide``)."""

    def __init__(self, layer):
        self.layer = layer
        self._padded = {}

    @property
    def size(self) -> int:
        return self.layer.covered.size

    def _images(self, width: int, rows: slice, cols: slice):
        # The G-buffer's shading normals are unit (or zero where nothing was drawn): not normalised again.
        layer = self.layer
        covered = np.asarray(layer.covered[rows, cols], bool)
        position = layer.position[rows, cols]
        x, y, z = (np.asarray(position[..., axis], np.float32) for axis in range(3))
        with np.errstate(invalid="ignore", over="ignore"):
            depth = np.where(covered, np.sqrt(x * x + y * y + z * z), np.inf)
        element = np.asarray(layer.element[rows, cols]).astype(np.int64)
        material = np.asarray(layer.material[rows, cols]).astype(np.int64)
        ids = np.where(covered, np.where(element >= 0, element, -2 - np.maximum(material, -1)), NO_ID)
        normal = layer.normal[rows, cols]
        return depth, [normal[..., axis] for axis in range(3)], ids


def layer_guide(layer) -> Guide:
    """The guide of a G-buffer layer (``raster.gbuffer.GBufferLayer``, (h, w) images): camera
    distance of its positions, its shading normals, and an id that is the element index where
    there is one and ``-2 - material`` elsewhere (surfaces of no element are told apart by
    material); NO_ID where nothing was drawn."""
    return _LayerGuide(layer)
