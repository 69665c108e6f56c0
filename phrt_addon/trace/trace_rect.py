"""Where on screen a frame's traced effects can change pixels: the rectangle of the G-buffer
that the read-back before tracing and the trace stage need.

Reflections and refractions leave from their elements' own pixels: the projection of those
elements' bounds (``gbuffer.points_rect`` of their corners).  A shadow changes the receivers in
its caster's shadow region (``shadow_region.shadow_region``: a cylinder downstream of the caster for the sun,
a cone from a local light), which is unbounded; but a receiver is a surface of the scene, so
it lies in the scene's bounds, and within them the region is held by a convex hull of 16
points (two boxes across the cylinder or the cone, at its near and far ends).  The hull is
clipped by the camera's near plane and projected: every pixel whose surface the region
holds, in any layer, lies in the rectangle.  A frame tracing a small caster's shadows then
reads back, tiles and tests the pixels of that rectangle, not the whole frame (the read-back
and the tiles of the layers were 7.5 of the 12.8 ms a frame traced one statue's 180 shadow
rays in, atrium path1 at 320x240).
"""
from __future__ import annotations

import numpy as np

from ..raster.gbuffer import EMPTY, RECT_MAX_SHARE, RECT_PAD, ndc_rects, points_rect
from ..scene import lights, shading
from ..scene.snapshot import box_corners

# The hull is grown by this share of its scale (and the region's radius by it): float64
# rounding between the region's test and the projection, far below a pixel.
SLACK = 1e-6


def shadow_hull(light, bounds, scene_bounds) -> np.ndarray | None:
    """(16, 3) world points whose convex hull holds every point of the box ``scene_bounds``
    (low, high) that ``shadow_region(light, bounds, .)`` accepts; None when that is not
    bounded (a local light inside the caster's bounding sphere: the region is everything)."""
    low, high = (np.asarray(b, np.float64) for b in bounds)
    scene_low, scene_high = (np.asarray(b, np.float64) for b in scene_bounds)
    centre = (low + high) / 2.0
    radius = 0.5 * float(np.linalg.norm(high - low)) + 1e-6
    # A receiver and the caster's centre both lie in the scene's bounds: no farther apart than
    # its diagonal (the caster is one of the scene's meshes).
    diagonal = float(np.linalg.norm(np.maximum(scene_high, high) - np.minimum(scene_low, low)))
    scale = diagonal + float(np.abs(centre).max()) + radius
    if lights.kind(light) is lights.LightKind.SUN:
        direction = shading.normalize(np.asarray(light.direction, dtype=np.float64))
        # The cylinder of the caster's sphere from ``radius`` upstream to where it leaves the
        # scene's bounds downstream (a point of it is within ``radius`` of the axis on each
        # coordinate), ``diagonal`` at most.
        far = min(diagonal, _exit(centre, direction, radius, 0.0, scene_low, scene_high))
        ends = np.stack([centre - radius * direction, centre + max(far, -radius) * direction])
        across = np.full(2, radius)
    else:
        origin = np.asarray(light.position, dtype=np.float64)
        to_centre = centre - origin
        distance = float(np.linalg.norm(to_centre))
        if not distance > radius * (1.0 + SLACK):
            return None
        axis = to_centre / distance
        cos_cone = np.sqrt(max(1.0 - (radius / distance) ** 2, 0.0))
        tan_cone = radius / max(distance * cos_cone, 1e-300)
        # Along the axis: from the nearest point the region accepts (farther than distance -
        # radius from the light, within the cone) to the farthest receiver (the light's distance
        # to the caster plus the scene's diagonal); across it, the cone's radius there.
        near = (distance - radius) * cos_cone
        far = min(distance + diagonal, _exit(origin, axis, 0.0, tan_cone, scene_low, scene_high))
        along = np.array([near, max(far, near)])
        ends = origin + along[:, None] * axis
        across = along * tan_cone
    across = across * (1.0 + SLACK) + SLACK * scale
    corners = box_corners(ends - across[:, None], ends + across[:, None]).reshape(-1, 3)
    return corners if np.all(np.isfinite(corners)) else None


def _exit(start, axis, reach, spread, low, high) -> float:
    """The largest t at which a point within ``reach + t * spread`` of ``start + t * axis`` on
    each coordinate can still be inside the box (low, high): the slabs' exits (inf: none)."""
    t = np.inf
    with np.errstate(divide="ignore", invalid="ignore"):
        rising = axis - spread  # the least a coordinate grows by per unit t, on the way up
        falling = axis + spread  # the most it grows by (below 0: the way down)
        up = np.where(rising > 0, (high + reach - start) / rising, np.inf)
        down = np.where(falling < 0, (low - reach - start) / falling, np.inf)
    exits = np.concatenate([up, down])
    exits = exits[np.isfinite(exits)]
    return float(min(t, exits.min())) if len(exits) else t


def union_rect(rects, width: int, height: int):
    """The rectangle holding every one of ``rects`` (EMPTY ones left out); None when one is None
    (the whole frame) or the union is over RECT_MAX_SHARE of the frame; one pixel when all are
    EMPTY."""
    if not rects or any(rect is None for rect in rects):
        return None
    rects = [rect for rect in rects if rect[2] > 0 and rect[3] > 0]
    if not rects:
        return 0, 0, min(1, int(width)), min(1, int(height))
    x0 = min(rect[0] for rect in rects)
    y0 = min(rect[1] for rect in rects)
    x1 = max(rect[0] + rect[2] for rect in rects)
    y1 = max(rect[1] + rect[3] for rect in rects)
    if (x1 - x0) * (y1 - y0) > RECT_MAX_SHARE * width * height:
        return None
    return x0, y0, x1 - x0, y1 - y0


def trace_rect(snapshot, wanted: dict, element_bounds, scene_bounds, width: int, height: int, hulls=None):
    """The rectangle holding every pixel the traced effects ``wanted`` ({effect: (n,) bool},
    ``trace_result.traced_effects``) can change or cast rays from, or None (read the whole frame).
    ``hulls``: a replay's ``ShadowHulls`` (None: each hull computed)."""
    rects = []
    leaving = np.flatnonzero(wanted["reflections"] | wanted["refractions"])
    boxes = [element_bounds[i] for i in leaving if element_bounds[i] is not None]
    if boxes:
        rects.append(points_rect(snapshot.camera, box_corners([box[0] for box in boxes], [box[1] for box in boxes]),
                                 width, height))
    casters = [i for i in np.flatnonzero(wanted["shadows"]) if element_bounds[i] is not None]
    shadow_lights = [light for light in snapshot.lights if light.cast_shadows]
    if casters and shadow_lights:
        if scene_bounds is None:
            return None
        hull_of = hulls if hulls is not None else shadow_hull
        hull_points = [hull_of(light, element_bounds[caster], scene_bounds)
                       for light in shadow_lights for caster in casters]
        if any(hull is None for hull in hull_points):
            return None
        rects.extend(points_rects(snapshot.camera, np.stack(hull_points), width, height))
    return union_rect(rects, width, height) if rects else None


class ShadowHulls:
    """``shadow_hull`` kept per replay for the values it depends on (the light's kind and
    position or direction, the caster's and the scene's bounds): a static caster's and light's
    hull is computed once, not every frame.  Hulls are read-only."""

    MAX_KEPT = 4096  # moving casters or lights make new keys: then it starts over

    def __init__(self):
        self._hulls = {}

    def __call__(self, light, bounds, scene_bounds):
        kind = lights.kind(light)
        key = (kind.name, _values(light.direction) if kind is lights.LightKind.SUN else _values(light.position),
               _values(bounds[0]), _values(bounds[1]), _values(scene_bounds[0]), _values(scene_bounds[1]))
        if key not in self._hulls:
            if len(self._hulls) >= self.MAX_KEPT:
                self._hulls.clear()
            hull = shadow_hull(light, bounds, scene_bounds)
            if hull is not None:
                hull.flags.writeable = False
            self._hulls[key] = hull
        return self._hulls[key]


def _values(vector) -> tuple:
    return tuple(np.asarray(vector, np.float64).ravel().tolist())


def points_rects(camera, point_sets, width: int, height: int, pad: int = RECT_PAD) -> list:
    """``points_rect`` of each (k, 3) set of ``point_sets`` (P, k, 3), the same rectangles: the
    sets wholly in front of the near plane projected in one product and measured together
    (five lights' shadow hulls cost 1.2 ms one at a time), the others one at a time."""
    sets = np.asarray(point_sets, np.float64)
    if sets.ndim != 3 or sets.shape[2] != 3:
        raise ValueError(f"point sets of shape {sets.shape}, expected (sets, points, 3)")
    n_sets, k = sets.shape[:2]
    if n_sets == 0 or k == 0:
        return [EMPTY] * n_sets  # no point: nothing on screen (as points_rect)
    matrix = np.asarray(camera.projection, np.float64) @ camera.view_matrix
    with np.errstate(invalid="ignore", over="ignore"):  # an infinite point: not finite, read whole
        clip = (sets.reshape(-1, 3) @ matrix[:, :3].T + matrix[:, 3]).reshape(n_sets, k, 4)
        simple = np.isfinite(clip).all(axis=(1, 2)) & (clip[..., 2] + clip[..., 3] >= 0.0).all(axis=1) \
            & (clip[..., 3] > 0.0).all(axis=1)
    rects = [None if flag else points_rect(camera, sets[index], width, height, pad)
             for index, flag in enumerate(simple.tolist())]
    if not simple.any():
        return rects
    front = clip[simple]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ndc = front[..., :2] / front[..., 3:4]
    finite = np.isfinite(ndc).all(axis=(1, 2))
    ndc = np.clip(np.where(np.isfinite(ndc), ndc, 0.0), -4.0, 4.0)
    for index, ok, rect in zip(np.flatnonzero(simple).tolist(), finite.tolist(),
                               ndc_rects(ndc.min(axis=1), ndc.max(axis=1), width, height, pad)):
        rects[index] = rect if ok else None
    return rects

