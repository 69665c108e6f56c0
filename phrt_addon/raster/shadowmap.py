"""Raster shadows: light views for shadow maps and their lookup in numpy.

The GPU draws the depth maps (``engine/gpu/shadow_maps.py``); everything else is here so
it is tested without Blender.  Sun lights get one orthographic view fitted to
the scene bounds, spot lights one perspective view covering the cone, point and
area lights six 90-degree cube faces.

Precision: every view keeps an ``origin`` (scene centre for the sun, the light
position otherwise) and its matrices act on positions relative to it, so huge
world coordinates do not cost float32 precision on the GPU.

Lookup: 2x2 percentage-closer filtering with a normal offset of 1.5 texels and
a comparison in linear light-space depth.  The GPU does the same lookup in GLSL
(``engine/gpu/lighting_glsl.py`` ``shadow_lit``); this numpy version is the reference it is tested against
(``phrt_addon/raster/reference_raster.py``).  The result is the raster shadow the
ray tracer replaces for selected casters (its softness and blockiness are what
ray traced shadows improve on).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..scene import lights

NORMAL_OFFSET_TEXELS = 1.5
DEPTH_BIAS_TEXELS = 1.0


@dataclass
class LightView:
    origin: np.ndarray  # (3,) float64
    view: np.ndarray  # (4,4) float64, acts on positions relative to origin
    projection: np.ndarray  # (4,4) float64
    size: int
    ortho: bool
    near: float
    far: float
    texel_angle: float  # perspective: radians per texel; ortho: metres per texel

    @property
    def view_proj_relative(self) -> np.ndarray:
        return self.projection @ self.view


@dataclass
class ShadowMap:
    """One view's map as numpy: ``linear`` is the light-space depth along the view axis per
    texel (what the GPU stores, R32F), flat, row 0 at the bottom.

    GLSL twin: engine/gpu/shadow_maps.py SHADOW_FRAG.main (the linear light-space depth per texel)"""

    view: LightView
    depth: np.ndarray | None = None  # (size, size) float32 window depth in [0, 1] (hardware depth)
    linear: np.ndarray | None = None

    def __post_init__(self):
        if self.linear is None:
            self.linear = _linear_depth(self.view, self.depth.astype(np.float64)).astype(np.float32).ravel()
        else:
            self.linear = np.ascontiguousarray(self.linear, dtype=np.float32).ravel()

    @classmethod
    def from_linear(cls, view: LightView, linear: np.ndarray) -> "ShadowMap":
        return cls(view=view, linear=linear)


def look_at(forward, up_hint=(0.0, 0.0, 1.0)) -> np.ndarray:
    """View rotation (4x4) looking along ``forward`` (camera -Z) from the origin."""
    forward = np.asarray(forward, dtype=np.float64)
    forward = forward / max(np.linalg.norm(forward), 1e-300)
    up = np.asarray(up_hint, dtype=np.float64)
    if abs(np.dot(up, forward)) > 0.99:
        up = np.array([0.0, 1.0, 0.0]) if abs(forward[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    true_up = np.cross(right, forward)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, true_up, -forward
    return view


def perspective(fov, near, far) -> np.ndarray:
    focal = 1.0 / np.tan(fov / 2.0)
    projection = np.zeros((4, 4))
    projection[0, 0] = projection[1, 1] = focal
    projection[2, 2] = (far + near) / (near - far)
    projection[2, 3] = 2.0 * far * near / (near - far)
    projection[3, 2] = -1.0
    return projection


def orthographic(left, right, bottom, top, near, far) -> np.ndarray:
    projection = np.eye(4)
    projection[0, 0] = 2.0 / (right - left)
    projection[1, 1] = 2.0 / (top - bottom)
    projection[2, 2] = -2.0 / (far - near)
    projection[0, 3] = -(right + left) / (right - left)
    projection[1, 3] = -(top + bottom) / (top - bottom)
    projection[2, 3] = -(far + near) / (far - near)
    return projection


CUBE_FACES = ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1))


def cube_face_view(points) -> tuple[np.ndarray, np.ndarray]:
    """(face index into CUBE_FACES, (N, 3) view coordinates (right, up, forward)) of points
    relative to a cube map's centre: each face's view (``look_at`` of its axis) is a signed
    permutation of the axes, so the GLSL lookup (``engine/gpu/lighting_glsl.py``, ``cube_face_view``)
    computes it with selects instead of reading a matrix per pixel.  Ties go to x, then y
    (as the GLSL).

    GLSL twin: engine/gpu/lighting_glsl.py cube_face_view"""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    a = np.abs(p)
    x_major = (a[:, 0] >= a[:, 1]) & (a[:, 0] >= a[:, 2])
    y_major = ~x_major & (a[:, 1] >= a[:, 2])
    along = np.where(x_major, p[:, 0], np.where(y_major, p[:, 1], p[:, 2]))
    sign = np.where(along < 0.0, -1.0, 1.0)
    face = np.where(x_major, 0, np.where(y_major, 2, 4)) + (along < 0.0)
    view = np.where(x_major[:, None], np.stack([-sign * p[:, 1], p[:, 2], sign * p[:, 0]], 1),
                    np.where(y_major[:, None], np.stack([sign * p[:, 0], p[:, 2], sign * p[:, 1]], 1),
                             np.stack([-sign * p[:, 0], p[:, 1], sign * p[:, 2]], 1)))
    return face.astype(np.int64), view


def _corners(bounds):
    low, high = (np.asarray(b, dtype=np.float64) for b in bounds)
    return np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])])


def light_views(light, bounds, size) -> list[LightView]:
    """The shadow-map views of ``light`` covering the scene ``bounds`` ((min, max) world).

    GLSL twin: engine/gpu/shadow_maps.py SHADOW_VERT.main (each view's view_proj_relative and axis)"""
    low, high = (np.asarray(b, dtype=np.float64) for b in bounds)
    extent = max(float(np.max(high - low)), 1e-6)
    corners = _corners(bounds)
    kind = lights.kind(light)
    if kind is lights.LightKind.SUN:
        origin = (low + high) / 2.0
        view = look_at(light.direction)
        local = (corners - origin) @ view[:3, :3].T
        margin = 0.01 * extent
        left, bottom = local[:, 0].min() - margin, local[:, 1].min() - margin
        right, top = local[:, 0].max() + margin, local[:, 1].max() + margin
        near, far = -local[:, 2].max() - margin, -local[:, 2].min() + margin
        span = max(right - left, top - bottom)
        return [LightView(origin, view, orthographic(left, right, bottom, top, near, far), size, True,
                          near, far, span / size)]
    origin = np.asarray(light.position, dtype=np.float64)
    distances = np.linalg.norm(corners - origin, axis=1)
    far = max(float(distances.max()), 1e-3) * 1.01
    near = max(far * 1e-4, 1e-4 * extent, 1e-6)
    if kind is lights.LightKind.SPOT:
        fov = min(float(light.spot_size) * 1.05 + 0.02, np.radians(170.0))
        return [LightView(origin, look_at(light.direction), perspective(fov, near, far), size, False,
                          near, far, fov / size)]
    face_size = max(size // 2, 64)
    return [LightView(origin, look_at(face), perspective(np.pi / 2.0, near, far), face_size, False,
                      near, far, (np.pi / 2.0) / face_size) for face in CUBE_FACES]


def _linear_depth(view: LightView, window_depth):
    """Window depth in [0,1] -> distance along the light's view axis."""
    if view.ortho:
        return view.near + window_depth * (view.far - view.near)
    z_ndc = window_depth * 2.0 - 1.0
    n, f = view.near, view.far
    return 2.0 * n * f / np.maximum(f + n - z_ndc * (f - n), 1e-300)


def _texel_size(view: LightView, relative):
    """World size of a texel at each point (relative to the view origin): the normal offset
    and the depth bias are multiples of it."""
    if view.ortho:
        return np.full(len(relative), view.texel_angle, relative.dtype)
    axis_depth = -(relative @ view.view[2, :3].astype(relative.dtype))
    return (view.texel_angle * np.maximum(axis_depth, view.near)).astype(relative.dtype)


def _lookup_one(shadow_map: ShadowMap, offset_points, texel):
    """Lit fraction in [0,1] for normal-offset points (relative to the view's origin) seen by
    one view; NaN where outside this view.  Works in the points' precision."""
    view = shadow_map.view
    dtype = offset_points.dtype
    rotation = view.view[:3, :3].astype(dtype)
    view_proj = view.view_proj_relative.astype(dtype)
    clip = offset_points @ view_proj[:3, :3].T + view_proj[:3, 3]
    w = offset_points @ view_proj[3, :3] + view_proj[3, 3]
    valid = w > 1e-12
    safe_w = np.where(valid, w, 1.0)
    ndc = clip / safe_w[:, None]
    inside = valid & np.all(np.abs(ndc[:, :2]) <= 1.0, axis=1) & (ndc[:, 2] <= 1.0)
    receiver_depth = -(offset_points @ rotation[2])
    size = view.size
    u = (ndc[:, 0] * 0.5 + 0.5) * size - 0.5
    v = (ndc[:, 1] * 0.5 + 0.5) * size - 0.5
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = u - u0, v - v0
    u0 = np.nan_to_num(u0, nan=0.0, posinf=0.0, neginf=0.0).astype(np.int64)
    v0 = np.nan_to_num(v0, nan=0.0, posinf=0.0, neginf=0.0).astype(np.int64)
    lit = np.zeros(len(offset_points), np.float32)
    threshold = (receiver_depth - DEPTH_BIAS_TEXELS * texel).astype(np.float32)
    x0 = np.clip(u0, 0, size - 1)
    x1 = np.clip(u0 + 1, 0, size - 1)
    row0 = np.clip(v0, 0, size - 1) * size
    row1 = np.clip(v0 + 1, 0, size - 1) * size
    fu = fu.astype(np.float32)
    fv = fv.astype(np.float32)
    linear = shadow_map.linear
    for index, weight in ((row0 + x0, (1 - fu) * (1 - fv)), (row0 + x1, fu * (1 - fv)),
                          (row1 + x0, (1 - fu) * fv), (row1 + x1, fu * fv)):
        lit += weight * (threshold <= linear[index])
    return np.where(inside, lit, np.nan)


def _cube_face(points):
    """Cube face index (+x, -x, +y, -y, +z, -z order of CUBE_FACES) of each point's major axis."""
    axis = np.argmax(np.abs(points), axis=1)
    negative = np.take_along_axis(points, axis[:, None], axis=1)[:, 0] < 0
    return axis * 2 + negative


def shadow_visibility(shadow_maps, points, normals, origin=None) -> np.ndarray:
    """Lit fraction in [0,1] of each point for one light's maps.  ``points`` (N,3) are world
    positions, or positions relative to ``origin`` (e.g. camera-relative float32 G-buffer
    positions: the lookup then runs in float32).  Points outside every map are lit (nothing
    was drawn there to occlude them).

    GLSL twin: engine/gpu/lighting_glsl.py shadow_lit"""
    if origin is None:
        points = np.asarray(points, dtype=np.float64)
        origin = np.zeros(3)
    points = np.asarray(points)
    normals = np.asarray(normals, dtype=points.dtype)
    if len(points) == 0 or not shadow_maps:
        return np.ones(len(points))
    # Every view of one light shares its origin.
    relative = points + (np.asarray(origin, np.float64) - shadow_maps[0].view.origin).astype(points.dtype)
    if len(shadow_maps) == 6:
        # Cube: the texel size from the face of the point, the face looked up from the offset
        # point (near a seam the offset can cross into the neighbouring face).
        first = _cube_face(relative)
        texel = np.empty(len(points), relative.dtype)
        for index, shadow_map in enumerate(shadow_maps):
            chosen = first == index
            if np.any(chosen):
                texel[chosen] = _texel_size(shadow_map.view, relative[chosen])
        offset_points = relative + normals * (NORMAL_OFFSET_TEXELS * texel)[:, None]
        face = _cube_face(offset_points)
        result = np.ones(len(points))
        for index, shadow_map in enumerate(shadow_maps):
            chosen = face == index
            if np.any(chosen):
                lit = _lookup_one(shadow_map, offset_points[chosen], texel[chosen])
                result[chosen] = np.where(np.isnan(lit), 1.0, lit)
        return result
    texel = _texel_size(shadow_maps[0].view, relative)
    offset_points = relative + normals * (NORMAL_OFFSET_TEXELS * texel)[:, None]
    lit = _lookup_one(shadow_maps[0], offset_points, texel)
    return np.where(np.isnan(lit), 1.0, lit)
