"""Face normals of G-buffer pixels: where secondary rays leave from.

Decoded from the layer's own face normals when the G-buffer pass wrote them (a frame that may
trace: ``engine/gpu/gbuffer.py``), else per pixel from the layer's positions; component by
component in float64: a frame's shadow pixels are tens of thousands, and numpy's (n, 3)
fancy indexing, masks and broadcasts cost several times its 1-D arithmetic (35k pixels at
320x240: 15 -> 7 ms).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..gather import take_rows

if TYPE_CHECKING:
    from .gbuffer import GBufferLayer


def _columns(image: np.ndarray, flat: np.ndarray) -> list:
    """float64 x, y, z of an (h, w, 3) image at the flat pixels ``flat``, as three 1-D arrays
    (``gather.take_rows``: ``np.take`` of rows is several times faster than fancy indexing, and
    1-D arithmetic than (n, 3) broadcasts)."""
    rows = take_rows(image.reshape(-1, 3), flat).T
    return [rows[axis].astype(np.float64) for axis in range(3)]


def geometric_normals(layer: GBufferLayer, flat: np.ndarray, view_directions: np.ndarray) -> np.ndarray:
    """Unit face normals at the layer's pixels ``flat`` (flat indices), facing the camera:
    where secondary rays leave from (``phrt_addon/trace/tracer.py``: offsets along the geometric
    normal, not the interpolated one, which on a coarse smooth mesh can point below the
    surface).

    The layer's own ``geometric_normal`` when the raster pass wrote one (8 bits an axis: within
    a degree of the face's); otherwise the cross
    product of the position differences to the neighbouring pixels of the same surface
    (same material and element), taking on each axis the side with the smaller difference
    (the one least likely to straddle an edge).  Where no such pair exists, or the result
    disagrees with the shading normal's side, the direction back to the camera is used: a
    point seen by the camera is always free on that side.  ``view_directions`` (n, 3):
    unit directions from the camera to the points."""
    flat = np.asarray(flat, np.int64)
    view = np.asarray(view_directions, np.float64).reshape(-1, 3)
    towards_camera = [-view[:, axis] for axis in range(3)]
    height, width = layer.covered.shape
    if layer.geometric_normal is not None:
        # As the pass stored it (``gbuffer.encode_face_normals``): decoded and made unit again.
        rows = take_rows(layer.geometric_normal.reshape(-1, 4), flat).T
        normal = [rows[axis] * (1.0 / 127.5) - 1.0 for axis in range(3)]
        length = np.sqrt(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2])
        found = (rows[3] >= 128) & (length > 0.5)
        inverse = np.divide(1.0, length, out=np.zeros(len(flat)), where=found)  # 0 where none: a zero normal
        normal = [component * inverse for component in normal]
    else:
        size = height * width
        covered = layer.covered.ravel()
        # The same surface: same material and element (read only at the pixels compared, not
        # built for the whole frame: a frame with few rays asks for few pixels).
        material, element = layer.material.ravel(), layer.element.ravel()
        material_here, element_here = material[flat], element[flat]
        ys, xs = np.divmod(flat, width)
        here = _columns(layer.position, flat)

        def neighbour(index, inside):
            """(position - here per axis, squared length (inf where not the same surface), ok)."""
            ok = inside & covered[index] & (material[index] == material_here) & (element[index] == element_here)
            delta = _columns(layer.position, index)
            for axis in range(3):
                delta[axis] -= here[axis]
            length = delta[0] * delta[0] + delta[1] * delta[1] + delta[2] * delta[2]
            return delta, np.where(ok, length, np.inf), ok

        def difference(step, coordinate, limit):
            forward, forward_length, forward_ok = neighbour(np.minimum(flat + step, size - 1), coordinate + 1 < limit)
            backward, backward_length, backward_ok = neighbour(np.maximum(flat - step, 0), coordinate > 0)
            use_forward = forward_length <= backward_length
            return [np.where(use_forward, ahead, -behind) for ahead, behind in zip(forward, backward)], \
                forward_ok | backward_ok

        (a0, a1, a2), ok_x = difference(1, xs, width)
        (b0, b1, b2), ok_y = difference(width, ys, height)
        normal = [a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0]
        length = np.sqrt(normal[0] * normal[0] + normal[1] * normal[1] + normal[2] * normal[2])
        found = ok_x & ok_y & (length > 0) & np.isfinite(length)
        normal = [np.where(found, component / np.where(found, length, 1.0), 0.0) for component in normal]
    # Face the camera; fall back to the camera direction where the normal is unusable.
    side = normal[0] * towards_camera[0] + normal[1] * towards_camera[1] + normal[2] * towards_camera[2]
    shading_normal = _columns(layer.normal, flat)
    shading_side = shading_normal[0] * towards_camera[0] + shading_normal[1] * towards_camera[1] + \
        shading_normal[2] * towards_camera[2]
    # The two normals agree once each faces the camera: the sign of their dot product, flipped
    # once for each that was turned.
    product = normal[0] * shading_normal[0] + normal[1] * shading_normal[1] + normal[2] * shading_normal[2]
    agree = np.where((side < 0) != (shading_side < 0), product < 0, product > 0)
    finite = np.isfinite(normal[0]) & np.isfinite(normal[1]) & np.isfinite(normal[2])
    usable = found & (np.abs(side) > 1e-6) & agree & finite
    flip = np.where(side < 0, -1.0, 1.0)
    # Built whole, then the few unusable rows replaced: writing three strided columns through
    # np.where took a third of the function (36,000 pixels: 1.0 of 3.4 ms).
    result = np.stack([normal[0] * flip, normal[1] * flip, normal[2] * flip], axis=1)
    unusable = np.flatnonzero(~usable)
    if len(unusable):
        result[unusable] = -view[unusable]
    return result
