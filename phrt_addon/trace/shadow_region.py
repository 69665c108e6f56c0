"""Shadow regions: which pixels a caster can shadow, per light.

For each light, the pixels whose segment to the light may cross an element's
bounds (a light-space cylinder for the sun, a cone for local lights) get traced
visibility when that element is selected as a shadow caster; elsewhere the shadow
map stays.  The same regions estimate each element's shadow-ray count for the
cost model.
"""
from __future__ import annotations

import math

import numpy as np

from ..scene import lights, shading


def shadow_region(light, bounds, points) -> np.ndarray:
    """Points (world, (N,3)) whose segment to ``light`` may pass through the box ``bounds``:
    the pixels an element can shadow.  Conservative (a bounding sphere or a light-space box).
    Column by column (numpy's (n, 3) products cost several times its 1-D arithmetic here)."""
    low, high = bounds
    centre = (low + high) / 2.0
    radius = 0.5 * float(np.linalg.norm(high - low)) + 1e-6
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if lights.kind(light) is lights.LightKind.SUN:
        d0, d1, d2 = (float(v) for v in shading.normalize(np.asarray(light.direction, dtype=np.float64)))
        x, y, z = (points[:, axis] - float(centre[axis]) for axis in range(3))
        along = x * d0 + y * d1 + z * d2  # > 0: downstream of the caster
        x -= along * d0
        y -= along * d1
        z -= along * d2
        return (along > -radius) & (x * x + y * y + z * z <= radius * radius)
    light_position = np.asarray(light.position, dtype=np.float64)
    to_centre = centre - light_position
    centre_distance = float(np.linalg.norm(to_centre))
    if centre_distance <= radius:
        return np.ones(len(points), bool)  # the light is inside the caster's bounds
    a0, a1, a2 = (float(v) for v in to_centre / centre_distance)
    x, y, z = (points[:, axis] - float(light_position[axis]) for axis in range(3))
    point_distance = np.sqrt(x * x + y * y + z * z)
    cos_point = (x * a0 + y * a1 + z * a2) / np.maximum(point_distance, 1e-30)
    cos_cone = np.sqrt(max(1.0 - (radius / centre_distance) ** 2, 0.0))
    return (cos_point >= cos_cone) & (point_distance > centre_distance - radius)


def _sun_basis(x: float, y: float, z: float) -> np.ndarray:
    """(3, 3) rows: two unit vectors across a sun's direction, then the direction (normalised),
    in plain floats (np.cross on two 3-vectors costs about 10 µs, twice a frame per sun)."""
    length = math.sqrt(x * x + y * y + z * z) or 1.0
    x, y, z = x / length, y / length, z / length
    hx, hy = (1.0, 0.0) if abs(x) < 0.9 else (0.0, 1.0)  # a helper axis not along the direction
    ax, ay, az = -z * hy, z * hx, x * hy - y * hx  # direction x helper
    length = math.sqrt(ax * ax + ay * ay + az * az) or 1.0
    ax, ay, az = ax / length, ay / length, az / length
    return np.array([[ax, ay, az], [y * az - z * ay, z * ax - x * az, x * ay - y * ax], [x, y, z]])


class ShadowRegionIndex:
    """``shadow_region`` for many casters and one light over the same points.

    The points' light-space coordinates are computed once per light: for the sun, two
    coordinates across the light and one along it; for local lights, the unit direction
    from the light and the distance.  A caster is then a few float32 operations per point.
    Once a light has ``SORT_AFTER_QUERIES`` casters, the points are also sorted by one
    coordinate, and each further caster tests only the window of points that can be in
    its cylinder or cone (a searchsorted range).  Same answer as ``shadow_region``."""

    SORT_AFTER_QUERIES = 6

    def __init__(self, light, points):
        self.light = light
        self.sun = lights.kind(light) is lights.LightKind.SUN  # parallel rays: a cylinder, not a cone
        points = np.asarray(points, dtype=np.float64)
        self.n = len(points)
        self.queries = 0
        self.order = None
        if self.sun:
            self.basis = _sun_basis(*np.asarray(light.direction, dtype=np.float64).tolist())
            self.coords = (points @ self.basis.T).astype(np.float32)  # (u, v) across, w along
        else:
            self.origin = np.asarray(light.position, dtype=np.float64)
            to_point = points - self.origin
            distance = np.sqrt(shading.dot(to_point, to_point))
            self.coords = np.concatenate([to_point / np.maximum(distance, 1e-30)[:, None], distance[:, None]],
                                         axis=1).astype(np.float32)  # unit direction, distance

    def _test(self, coords, bounds):
        low, high = bounds
        centre = (low + high) / 2.0
        radius = 0.5 * float(np.linalg.norm(high - low)) + 1e-6
        if self.sun:
            cu, cv, cw = self.basis @ centre
            du = coords[:, 0] - np.float32(cu)
            dv = coords[:, 1] - np.float32(cv)
            return (du * du + dv * dv <= np.float32(radius * radius)) & (coords[:, 2] > np.float32(cw - radius))
        to_centre = centre - self.origin
        distance = float(np.linalg.norm(to_centre))
        if distance <= radius:
            return np.ones(len(coords), bool)  # the light is inside the caster's bounds
        axis = (to_centre / distance).astype(np.float32)
        cos_cone = np.float32(np.sqrt(max(1.0 - (radius / distance) ** 2, 0.0)))
        return (coords[:, :3] @ axis >= cos_cone) & (coords[:, 3] > np.float32(distance - radius))

    def _window(self, bounds):
        """The index range of sorted points that may pass ``_test`` (a superset)."""
        low, high = bounds
        centre = (low + high) / 2.0
        radius = 0.5 * float(np.linalg.norm(high - low)) + 1e-6
        if self.sun:
            key = float(self.basis[0] @ centre)
            reach = radius
        else:
            to_centre = centre - self.origin
            distance = float(np.linalg.norm(to_centre))
            if distance <= radius:
                return 0, self.n
            # Unit directions within the cone's half angle t of the axis a satisfy |d_x - a_x| <= t.
            key = to_centre[0] / distance
            reach = float(np.arcsin(min(radius / distance, 1.0)))
        margin = 1e-5 * (abs(key) + reach) + 1e-6  # float32 keys
        start = np.searchsorted(self.sorted_key, key - reach - margin, side="left")
        stop = np.searchsorted(self.sorted_key, key + reach + margin, side="right")
        return start, stop

    def counts(self, bounds_list, chunk: int = 1 << 18) -> np.ndarray:
        """(C,) int64: how many points each caster's region holds, ``count_nonzero(region(b))``
        for every ``b`` of ``bounds_list`` at once (casters by points, in blocks of about
        ``chunk`` tests: a frame's footprint sub-sample against all its casters in a few numpy
        calls instead of a few per caster)."""
        if not len(bounds_list) or self.n == 0:
            return np.zeros(len(bounds_list), np.int64)
        low = np.array([b[0] for b in bounds_list], np.float64).reshape(-1, 3)
        high = np.array([b[1] for b in bounds_list], np.float64).reshape(-1, 3)
        centre = (low + high) / 2.0
        radius = 0.5 * np.linalg.norm(high - low, axis=1) + 1e-6
        result = np.zeros(len(centre), np.int64)
        step = max(1, int(chunk) // self.n)
        coords = self.coords
        if self.sun:
            light_space = centre @ self.basis.T  # (C, 3): u, v across, w along
            cu, cv = light_space[:, 0].astype(np.float32), light_space[:, 1].astype(np.float32)
            reach = (radius * radius).astype(np.float32)
            downstream = (light_space[:, 2] - radius).astype(np.float32)
            for first in range(0, len(centre), step):
                part = slice(first, first + step)
                du = coords[None, :, 0] - cu[part, None]
                dv = coords[None, :, 1] - cv[part, None]
                inside = (du * du + dv * dv <= reach[part, None]) & (coords[None, :, 2] > downstream[part, None])
                result[part] = np.count_nonzero(inside, axis=1)
            return result
        to_centre = centre - self.origin
        distance = np.linalg.norm(to_centre, axis=1)
        enclosing = distance <= radius  # the light inside the caster's bounds: every point
        result[enclosing] = self.n
        cone = np.flatnonzero(~enclosing)
        if len(cone) == 0:
            return result
        axis = (to_centre[cone] / distance[cone, None]).astype(np.float32)
        cos_cone = np.sqrt(np.maximum(1.0 - (radius[cone] / distance[cone]) ** 2, 0.0)).astype(np.float32)
        nearest = (distance[cone] - radius[cone]).astype(np.float32)
        for first in range(0, len(cone), step):
            part = slice(first, first + step)
            inside = ((axis[part] @ coords[:, :3].T) >= cos_cone[part, None]) & \
                (coords[None, :, 3] > nearest[part, None])
            result[cone[part]] = np.count_nonzero(inside, axis=1)
        return result

    def region(self, bounds) -> np.ndarray:
        self.queries += 1
        if self.queries <= self.SORT_AFTER_QUERIES:
            return self._test(self.coords, bounds)
        if self.order is None:
            self.order = np.argsort(self.coords[:, 0], kind="stable")
            self.sorted_key = self.coords[self.order, 0]
            self.sorted_coords = self.coords[self.order]
        start, stop = self._window(bounds)
        result = np.zeros(self.n, bool)
        result[self.order[start:stop]] = self._test(self.sorted_coords[start:stop], bounds)
        return result


class PointChunks:
    """The points in small groups with a bounding sphere each (float64): a caster's cylinder or
    cone that misses a sphere misses all of its points.  ``keys``: a group id per point (a
    pixel's screen tile: compact groups); without them, runs of ``size`` consecutive points
    (points in pixel order make runs along a row)."""

    def __init__(self, points, keys=None, size: int = 64):
        points = np.asarray(points, dtype=np.float64)
        self.n = len(points)
        if keys is None:
            self.order = None
            self.starts = np.arange(0, self.n, int(size))
        else:
            keys = np.asarray(keys)
            if keys.shape != (self.n,):
                raise ValueError(f"{keys.shape} keys for {self.n} points")
            self.order = np.argsort(keys, kind="stable")
            keys = keys[self.order]
            points = points[self.order]
            self.starts = np.flatnonzero(np.r_[True, keys[1:] != keys[:-1]]) if self.n else np.zeros(0, np.int64)
        self.counts = np.diff(np.r_[self.starts, self.n])
        if self.n == 0:
            self.centre, self.radius = np.zeros((0, 3)), np.zeros(0)
            return
        low = np.minimum.reduceat(points, self.starts, axis=0)
        high = np.maximum.reduceat(points, self.starts, axis=0)
        if np.isnan(low).any() or np.isnan(high).any():
            # A NaN point (no surface) must not hide the others of its group (fmin ignores NaN,
            # at twice the cost); a group of NaN only, or with an infinite point, keeps
            # non-finite bounds and every caster tests its points.
            low = np.fmin.reduceat(points, self.starts, axis=0)
            high = np.fmax.reduceat(points, self.starts, axis=0)
        self.centre = (low + high) / 2.0
        with np.errstate(invalid="ignore", over="ignore"):
            self.radius = 0.5 * np.sqrt(np.sum((high - low) ** 2, axis=1))

    def points_of(self, chunks: np.ndarray) -> np.ndarray:
        """Indices of the points in the chunks ``chunks`` (a boolean mask over chunks)."""
        starts, counts = self.starts[chunks], self.counts[chunks]
        total = int(counts.sum())
        if total == 0:
            return np.zeros(0, np.int64)
        # Consecutive ranges [start, start + count) without a Python loop.
        offsets = np.repeat(starts - np.r_[0, np.cumsum(counts)[:-1]], counts)
        idx = offsets + np.arange(total)
        return idx if self.order is None else self.order[idx]


class TiledShadowRegions:
    """``shadow_region`` for a few casters and one light over many points (a layer's pixels;
    ``ShadowRegionIndex`` suits many casters over few points).

    The points are grouped in runs (``PointChunks``, shareable between lights); a caster first
    tests the runs' bounding spheres against its cylinder (sun) or cone (local lights), then
    ``shadow_region`` runs on the points of the runs it may reach only.  A light whose casters
    shadow little of the frame costs little.  The same answer as ``shadow_region`` (float64,
    at any distance from the origin)."""

    def __init__(self, light, points, chunks: PointChunks | None = None):
        self.light = light
        self.sun = lights.kind(light) is lights.LightKind.SUN  # parallel rays: a cylinder, not a cone
        # ``points``: (n, 3), or a function of an index giving those points (float64 world), with
        # ``chunks`` given: only the points of reached chunks are then made (``LayerPixels.world``:
        # a few casters' regions over a layer of 76,800 pixels reach a few thousand).
        self._point_rows = points if callable(points) else None
        self.points = None if callable(points) else np.asarray(points, dtype=np.float64)
        if self.points is None and chunks is None:
            raise ValueError("points given as a function need their chunks")
        self.n = chunks.n if self.points is None else len(self.points)
        self.chunks = chunks if chunks is not None else PointChunks(self.points)
        if self.chunks.n != self.n:
            raise ValueError(f"chunks of {self.chunks.n} points for {self.n} points")
        self.queries = 0
        self.points_tested = 0
        if self.sun:
            self.direction = shading.normalize(np.asarray(light.direction, dtype=np.float64))
        else:
            self.origin = np.asarray(light.position, dtype=np.float64)

    def _chunks_reached(self, bounds_list) -> np.ndarray:
        """(casters, chunks) bool: the chunks whose bounding sphere may hold a point of each
        caster's region (conservative, with a margin for rounding); all casters of the light in
        one set of array operations (one caster at a time, a light of ten casters spent most of
        its time calling numpy on 1,200 tiles)."""
        low = np.array([bounds[0] for bounds in bounds_list], np.float64)
        high = np.array([bounds[1] for bounds in bounds_list], np.float64)
        centre = (low + high) / 2.0  # (casters, 3)
        radius = (0.5 * np.linalg.norm(high - low, axis=1) + 1e-6)[:, None]  # (casters, 1)
        chunk_centre, chunk_radius = self.chunks.centre, self.chunks.radius
        with np.errstate(invalid="ignore", over="ignore", divide="ignore"):  # a light at a caster's centre
            # float64 rounding: a few ulps of the largest magnitude involved
            slack = 1e-9 * ((np.abs(chunk_centre).max(axis=1) + chunk_radius)[None, :]
                            + np.abs(centre).max(axis=1)[:, None] + radius
                            + (0.0 if self.sun else float(np.abs(self.origin).max()))) + 1e-6
            reach = chunk_radius[None, :] + slack  # (casters, chunks)
            cx, cy, cz = (np.ascontiguousarray(chunk_centre[:, axis]) for axis in range(3))
            if self.sun:
                d0, d1, d2 = (float(v) for v in self.direction)
                x, y, z = (column[None, :] - centre[:, axis:axis + 1] for axis, column in enumerate((cx, cy, cz)))
                along = x * d0 + y * d1 + z * d2
                lateral = np.sqrt(np.maximum(x * x + y * y + z * z - along * along, 0.0))
                reached = (along + reach > -radius) & (lateral - reach <= radius)
            else:
                to_centre = centre - self.origin  # (casters, 3)
                distance = np.linalg.norm(to_centre, axis=1)[:, None]
                x, y, z = cx - self.origin[0], cy - self.origin[1], cz - self.origin[2]
                chunk_distance = np.sqrt(x * x + y * y + z * z)[None, :]
                dot = x[None, :] * to_centre[:, 0:1] + y[None, :] * to_centre[:, 1:2] + z[None, :] * to_centre[:, 2:3]
                cos_angle = np.clip(dot / np.maximum(chunk_distance * distance, 1e-300), -1.0, 1.0)
                # The widest angle a point of the sphere makes with the direction to its centre.
                spread = np.arcsin(np.clip(reach / np.maximum(chunk_distance, 1e-300), 0.0, 1.0))
                cone = np.arcsin(np.minimum(radius / distance, 1.0))
                reached = ((chunk_distance <= reach) | (np.arccos(cos_angle) <= cone + spread + 1e-4)) \
                    & (chunk_distance + reach > distance - radius)
                reached |= distance <= radius  # the light inside the caster's bounds: every chunk
            # Unknown bounds (a NaN or infinite point in the group): its points are tested.
            reached |= ~np.isfinite(chunk_radius)[None, :]
        return reached

    def regions(self, bounds_list) -> list:
        """``region`` of each of ``bounds_list`` (the casters of this light), the chunks tested
        for all of them at once."""
        bounds_list = list(bounds_list)
        if not bounds_list:
            return []
        out = []
        for bounds, reached in zip(bounds_list, self._chunks_reached(bounds_list)):
            self.queries += 1
            result = np.zeros(self.n, bool)
            idx = self.chunks.points_of(reached)
            if len(idx):
                self.points_tested += len(idx)
                with np.errstate(invalid="ignore", over="ignore"):  # a non-finite point is in no region
                    result[idx] = shadow_region(self.light, bounds, self._points(idx))
            out.append(result)
        return out

    def region(self, bounds) -> np.ndarray:
        return self.regions([bounds])[0]

    def _points(self, idx) -> np.ndarray:
        if self.points is None:
            return np.asarray(self._point_rows(idx), np.float64)
        return self.points[idx]
