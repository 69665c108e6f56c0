"""G-buffer: what the raster pass leaves for shading, selection and tracing.

Two layers, both (h, w) images with row 0 at the bottom (Blender's pixel order):
``opaque`` holds the nearest opaque surface, ``transparent`` the nearest
transparent surface in front of it (glass, water, alpha-blended cards).  The
raster pass fills them on the GPU (``engine/gpu/gbuffer.py``); tests may build them
by hand.

Positions are stored relative to ``origin`` (the camera position, float64) so
that float32 keeps its precision at huge world coordinates.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..scene.snapshot import box_corners


@dataclass
class GBufferLayer:
    """One layer of the G-buffer: what the raster pass leaves per pixel (below).

    GLSL twin: engine/gpu/gbuffer.py GBUFFER_VERT.main (the position relative to the camera)
    GLSL twin: engine/gpu/gbuffer.py GBUFFER_FRAG.main (what one layer holds per pixel)"""
    covered: np.ndarray  # (h, w) bool: a surface was drawn here
    position: np.ndarray  # (h, w, 3) float32, world position minus GBuffer.origin
    normal: np.ndarray  # (h, w, 3) float32 unit shading normal, facing the camera
    roughness: np.ndarray  # (h, w) float32
    albedo: np.ndarray  # (h, w, 3) float32 base colour (texture applied)
    metallic: np.ndarray  # (h, w) float32
    material: np.ndarray  # (h, w) int32 material index, -1 where not covered
    element: np.ndarray  # (h, w) int32 element index, -1 where none
    # (h, w, 4) uint8 face (geometric) normal as the raster pass writes it when the frame may
    # trace (``encode_face_normals``); otherwise ``geometric_normals`` reconstructs it from the
    # positions.
    geometric_normal: np.ndarray | None = None

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

    def cropped(self, rect) -> "GBufferLayer":
        """This layer as read back inside ``rect`` only (x, y, w, h; row 0 at the bottom): the
        other pixels as cleared ones (not covered, no material, no element), what
        ``engine/gpu/readback.py`` returns for a rectangle."""
        x, y, w, h = rect
        inside = np.zeros(self.covered.shape, bool)
        inside[y:y + h, x:x + w] = True

        def keep(array, cleared):
            if array is None:
                return None
            shape = inside.shape + (1,) * (array.ndim - 2)
            return np.where(inside.reshape(shape), array, np.asarray(cleared, array.dtype))

        return GBufferLayer(covered=keep(self.covered, False), position=keep(self.position, 0.0),
                            normal=keep(self.normal, 0.0), roughness=keep(self.roughness, 0.0),
                            albedo=keep(self.albedo, 0.0), metallic=keep(self.metallic, 0.0),
                            material=keep(self.material, -1), element=keep(self.element, -1),
                            geometric_normal=keep(self.geometric_normal, 0))


def encode_face_normals(normals: np.ndarray) -> np.ndarray:
    """(..., 3) face normals as the G-buffer pass stores them: (..., 4) uint8, each axis of the
    unit normal as round((n + 1) * 127.5), alpha 255 where it was found (a finite, non-zero
    vector) and 0 elsewhere (then (128, 128, 128)).  Decoded by ``normals.geometric_normals``.

    Written on the GPU by engine/gpu/gbuffer.py GBUFFER_FRAG (its ``out_geometric``), whose twin
    is ``GBufferLayer``."""
    normals = np.asarray(normals, np.float64)
    length = np.sqrt(np.sum(normals * normals, axis=-1, keepdims=True))
    found = (length > 0) & np.all(np.isfinite(normals), axis=-1, keepdims=True) & np.isfinite(length)
    unit = np.where(found, normals / np.where(found, length, 1.0), 0.0)
    encoded = np.rint((unit + 1.0) * 127.5).astype(np.uint8)
    return np.concatenate([encoded, np.where(found, 255, 0).astype(np.uint8)], axis=-1)


# Pixels added around the projected bounds of a read-back rectangle: a traced pixel's neighbours
# within the reconstruction's 5x5 (and the geometric normals' 3x3) are read back as they are.
RECT_PAD = 3
# A rectangle over this share of the frame is read whole (one call, no saving to speak of).
RECT_MAX_SHARE = 0.6


def screen_rect(camera, boxes, width: int, height: int, pad: int = RECT_PAD):
    """(x, y, w, h) pixels (row 0 at the bottom) holding the projection of every world box
    ``(low, high)`` of ``boxes``, grown by ``pad``; one pixel when none is on screen; None when
    the frame is better read whole (a box reaching behind the camera's plane or not finite, or
    the rectangle over RECT_MAX_SHARE of the frame).  Every pixel a surface inside the boxes
    covers, in any layer, lies within it."""
    boxes = [box for box in boxes if box is not None]
    if not boxes:
        return None
    corners = box_corners([box[0] for box in boxes], [box[1] for box in boxes]).reshape(-1, 3)
    w = np.c_[corners, np.ones(len(corners))] @ (np.asarray(camera.projection, np.float64) @ camera.view_matrix)[3]
    if not np.all(np.isfinite(w)) or np.any(w <= 0.0):
        return None  # behind or on the camera's plane
    rect = points_rect(camera, corners, width, height, pad)
    return (0, 0, min(1, int(width)), min(1, int(height))) if rect == EMPTY else rect


# A rectangle holding nothing (points off screen or behind the camera): left out of unions.
EMPTY = (0, 0, 0, 0)


def points_rect(camera, points, width: int, height: int, pad: int = RECT_PAD):
    """(x, y, w, h) pixels (row 0 at the bottom) holding the projection of the convex hull of
    ``points`` (world) in front of the projection's near plane, grown by ``pad``; EMPTY when
    none of it is on screen; None when the frame is better read whole (not finite, or over
    RECT_MAX_SHARE of it)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    with np.errstate(invalid="ignore", over="ignore"):  # an infinite point: not finite, read whole
        clip = np.c_[points, np.ones(len(points))] @ (np.asarray(camera.projection, np.float64) @ camera.view_matrix).T
    if not np.all(np.isfinite(clip)):
        return None
    # In front of the projection's own near plane (OpenGL clip space: z >= -w), the plane the
    # raster clipped at (not ``camera.clip_start``, which a viewport may give differently).
    ahead = clip[:, 2] + clip[:, 3]
    front = ahead >= 0.0
    kept = [clip[front]]
    if not front.all() and front.any():
        # Where the hull's edges cross the near plane: every pair of a point in front and one
        # behind (the hull's edges are among them; the others cross inside the hull).
        a, b = clip[front], clip[~front]
        fa, fb = ahead[front], ahead[~front]
        t = fa[:, None] / (fa[:, None] - fb[None, :])
        kept.append((a[:, None, :] + t[..., None] * (b[None, :, :] - a[:, None, :])).reshape(-1, 4))
    kept = np.concatenate(kept)
    if len(kept) == 0:
        return EMPTY  # behind the camera: nothing on screen
    if np.any(kept[:, 3] <= 0.0):
        return None  # a projection that is not a camera's: read whole
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ndc = kept[:, :2] / kept[:, 3:4]
    if not np.all(np.isfinite(ndc)):
        return None
    ndc = np.clip(ndc, -4.0, 4.0)  # beyond the frame either way (ints stay small)
    return ndc_rects(ndc.min(axis=0)[None], ndc.max(axis=0)[None], width, height, pad)[0]


def ndc_rects(low, high, width: int, height: int, pad: int = RECT_PAD) -> list:
    """Per row of ``low`` / ``high`` ((P, 2) finite NDC corners, within -4..4): the (x, y, w, h)
    pixels holding them, grown by ``pad``; EMPTY when off screen; None when over RECT_MAX_SHARE
    of the frame (``points_rect``'s last step, for one set or many)."""
    x0 = np.maximum(np.floor((low[:, 0] + 1.0) * 0.5 * width).astype(np.int64) - pad, 0)
    x1 = np.minimum(np.ceil((high[:, 0] + 1.0) * 0.5 * width).astype(np.int64) + pad, int(width))
    y0 = np.maximum(np.floor((low[:, 1] + 1.0) * 0.5 * height).astype(np.int64) - pad, 0)
    y1 = np.minimum(np.ceil((high[:, 1] + 1.0) * 0.5 * height).astype(np.int64) + pad, int(height))
    rects = []
    for a, b, c, d in zip(x0.tolist(), x1.tolist(), y0.tolist(), y1.tolist()):
        if b <= a or d <= c:
            rects.append(EMPTY)  # off screen
        elif (b - a) * (d - c) > RECT_MAX_SHARE * width * height:
            rects.append(None)
        else:
            rects.append((a, c, b - a, d - c))
    return rects



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
        """Element index of the front-most surface of each pixel (transparent over opaque).

        GLSL twin: engine/gpu/gbuffer.py RESOLVE_FRAG.main (and front_normal, view_depth)"""
        return np.where(self.transparent.covered, self.transparent.element, self.opaque.element)

    def front_normal(self) -> np.ndarray:
        return np.where(self.transparent.covered[..., None], self.transparent.normal, self.opaque.normal)


def element_pixel_stats(element_image: np.ndarray, n_elements: int, view_depth: np.ndarray, grid=None):
    """Per element, from the element-id image: pixel count, pixel centroid in NDC
    (-1..1) and mean view depth of its pixels (its finite depths).

    Whole-array numpy: one key per pixel, cut into runs of one key along each row (an id
    image is a few thousand runs: sums per run, then per element; 2.4 -> 0.9 ms at 320x240),
    or four bincounts over the pixels when runs are not much fewer (noise); elements with no
    pixels get count 0, centroid (0, 0) and depth inf.  This is the exact "area in the view plane" of
    the paper's A, measured rather than estimated from bounds.  ``grid`` (a ``PixelGrid``,
    optional) keeps the pixel coordinates from frame to frame."""
    height, width = element_image.shape
    image = np.asarray(element_image)
    if image.dtype.kind not in "iu":
        image = image.astype(np.int64)
    def keys(ids):
        # One key per id: 0 no element (id -1), 1..n the elements, n + 1 any other id.  Negative
        # ids + 1 seen as unsigned are beyond n + 1, so one minimum clips both ends (in place).
        key = ids.astype(np.int64)
        key += 1
        unsigned = key.view(np.uint64)
        np.minimum(unsigned, np.uint64(n_elements + 1), out=unsigned)
        return key

    ids = image.ravel()
    size = n_elements + 2
    depth_values = np.asarray(view_depth).ravel()
    if depth_values.size != ids.size:
        raise ValueError(f"view depth has {depth_values.size} values for {ids.size} pixels")
    # Runs of one id along a row (a coherent image: a few thousand), found on the ids as they are
    # (two ids beyond n in a row make two runs of one key: summed alike); keys for the runs only.
    runs = row_runs(ids, width)
    key = None
    if runs is not None:
        starts, lengths = runs
        run_key = keys(ids[starts])
        row, column = np.divmod(starts, width)
        counts = np.bincount(run_key, weights=lengths, minlength=size)[1:n_elements + 1].astype(np.int64)
        # A run's columns are column .. column + length - 1: their sum in closed form (exact in float64).
        column_sum = np.bincount(run_key, weights=lengths * column + lengths * (lengths - 1) / 2.0,
                                 minlength=size)[1:n_elements + 1]
        row_sum = np.bincount(run_key, weights=lengths * row, minlength=size)[1:n_elements + 1]
        depth_sum = np.bincount(run_key, weights=np.add.reduceat(depth_values, starts, dtype=np.float64),
                                minlength=size)[1:n_elements + 1]
    else:
        key = keys(ids)
        xs, ys = (grid or PixelGrid()).coordinates(height, width)
        counts = np.bincount(key, minlength=size)[1:n_elements + 1].astype(np.int64, copy=False)
        column_sum = np.bincount(key, weights=xs, minlength=size)[1:n_elements + 1]
        row_sum = np.bincount(key, weights=ys, minlength=size)[1:n_elements + 1]
        depth_sum = np.bincount(key, weights=depth_values, minlength=size)[1:n_elements + 1]
    safe = np.maximum(counts, 1)
    has_pixels = counts > 0
    # Mean pixel column and row, then to NDC (affine: the mean of the NDC is the NDC of the mean).
    centre = np.zeros((n_elements, 2))
    centre[has_pixels, 0] = ((column_sum / safe + 0.5) / width * 2.0 - 1.0)[has_pixels]
    centre[has_pixels, 1] = ((row_sum / safe + 0.5) / height * 2.0 - 1.0)[has_pixels]
    # Mean depth (bincount) rather than the median: O(n) and stable for convex-ish elements.  Only
    # when an element's sum is not finite (a pixel without a finite depth) are such pixels left out.
    depth_count = counts
    if not np.isfinite(depth_sum).all():
        key = keys(ids) if key is None else key
        finite = np.isfinite(depth_values)
        depth_sum = np.bincount(key, weights=np.where(finite, depth_values, 0.0), minlength=size)[1:n_elements + 1]
        depth_count = np.bincount(key[finite], minlength=size)[1:n_elements + 1]
    depth = np.where(depth_count > 0, depth_sum / np.maximum(depth_count, 1), np.inf)
    return counts, centre, depth


def row_runs(key: np.ndarray, width: int):
    """(starts, lengths) of the runs of one key along each row of the flat key image, or None
    when they are not at least 4x fewer than the pixels (noise: per-pixel sums are then faster)."""
    if key.size == 0:
        return None
    change = np.empty(key.size, bool)
    change[0] = True
    np.not_equal(key[1:], key[:-1], out=change[1:])
    change[::width] = True
    starts = np.flatnonzero(change)
    if 4 * len(starts) > key.size:
        return None
    lengths = np.diff(starts, append=key.size)
    return starts, lengths.astype(np.float64)


class PixelGrid:
    """(column, row) of every pixel in row order, float64 (bincount weights), kept for the last
    size asked: a replay's frames share it (0.6 ms a frame at 320x240, 3 at 640x480); also the
    NDC of front_points' sub-sample."""

    def __init__(self):
        self._size = None
        self._coordinates = None
        self._subsample = None  # ((height, width, step), (xs, ys)): front_points' NDC

    def subsample_ndc(self, height: int, width: int, step: int) -> tuple:
        """(x, y) NDC (-1..1, flat, row order) of the centres of every ``step``-th pixel from
        ``step // 2`` in x and y (front_points' sub-sample), kept for the last size asked."""
        if self._subsample is None or self._subsample[0] != (height, width, step):
            rows = (np.arange(step // 2, height, step) + 0.5) / height * 2.0 - 1.0
            cols = (np.arange(step // 2, width, step) + 0.5) / width * 2.0 - 1.0
            ys, xs = np.meshgrid(rows, cols, indexing="ij")
            xs, ys = xs.ravel(), ys.ravel()
            xs.flags.writeable = ys.flags.writeable = False
            self._subsample = ((height, width, step), (xs, ys))
        return self._subsample[1]

    def coordinates(self, height: int, width: int) -> tuple:
        if self._size != (height, width):
            xs = np.tile(np.arange(width, dtype=np.float64), height)
            ys = np.repeat(np.arange(height, dtype=np.float64), width)
            xs.flags.writeable = ys.flags.writeable = False
            self._size, self._coordinates = (height, width), (xs, ys)
        return self._coordinates


# Bytes per pixel of a G-buffer: two layers (covered bool; position, normal, albedo and the
# geometric normal float32x3; roughness, metallic float32; material, element int32) and the
# view depth (float32).
GBUFFER_BYTES_PER_PIXEL = 2 * (1 + 4 * 3 * 4 + 2 * 4 + 2 * 4) + 4


def gbuffer_bytes(width: int, height: int) -> int:
    return int(width) * int(height) * GBUFFER_BYTES_PER_PIXEL


def memory_available_bytes() -> int | None:
    """Memory this machine can still give (MemAvailable of /proc/meminfo, else physical pages)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


def resolution_problem(width: int, height: int, available: int | None = None) -> str | None:
    """Why a ``width`` x ``height`` frame cannot be rendered here (its G-buffer alone would not fit
    in the memory available), or None."""
    available = memory_available_bytes() if available is None else available
    needed = gbuffer_bytes(width, height)
    if available is None or needed <= available:
        return None
    return (f"resolution {width}x{height} needs about {needed / 2**30:.1f} GiB for its G-buffer alone, more than "
            f"the {available / 2**30:.1f} GiB of memory available: give a smaller --resolution")


def front_points(camera, view_depth, step, grid=None) -> np.ndarray:
    """World positions (float64) of every ``step``-th pixel in x and y with a surface, from its
    distance along the view axis: on the pixel's ray, interpolated between its near and far
    points (exact for perspective and orthographic views alike).  ``grid`` (a ``PixelGrid``,
    optional) keeps the sub-sample's NDC from frame to frame."""
    height, width = view_depth.shape
    # The sub-sample first, then to float64 (not the whole image: 1 ms a frame at 320x240).
    depth = np.asarray(view_depth)[step // 2::step, step // 2::step].astype(np.float64).ravel()
    xs, ys = (grid or PixelGrid()).subsample_ndc(height, width, step)
    covered = np.isfinite(depth)
    if not np.any(covered):
        return np.zeros((0, 3))
    inverse = np.linalg.inv(np.asarray(camera.projection, np.float64) @ camera.view_matrix)
    # (x, y) NDC times the inverse's first two columns, then each plane's z and w columns added.
    xy = xs[covered, None] * inverse[:, 0] + ys[covered, None] * inverse[:, 1]

    def unproject(z):
        clip = xy + (z * inverse[:, 2] + inverse[:, 3])
        return clip[:, :3] / clip[:, 3:4]

    near, far = unproject(-1.0), unproject(1.0)
    forward = camera.forward
    origin = camera.position @ forward
    near_depth = near @ forward - origin
    far_depth = far @ forward - origin
    along = (depth[covered] - near_depth) / np.where(np.abs(far_depth - near_depth) > 1e-30,
                                                     far_depth - near_depth, 1.0)
    points = near + (far - near) * along[:, None]
    return points[np.all(np.isfinite(points), axis=1)]
