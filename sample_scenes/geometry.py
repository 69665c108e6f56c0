"""Mesh geometry of the sample scenes as plain numpy arrays (no bpy).

A ``Part`` is a small polygon mesh (vertices, triangles and quads, optional
per-corner UVs, one material slot index). Closed primitives return parts whose
faces wind counter-clockwise seen from outside, so normals point out; a
``MeshData`` gathers parts into one Blender mesh (``blender_data.mesh_object``).
Everything here is deterministic: randomness comes in as a seeded
``numpy.random.Generator``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .transforms import scale

_NO_TRIS = np.zeros((0, 3), dtype=np.int32)
_NO_QUADS = np.zeros((0, 4), dtype=np.int32)


@dataclass
class Part:
    """Vertices ``(V, 3)``, triangles ``(T, 3)`` and quads ``(Q, 4)`` over
    them, optional per-corner UVs of each (``(T, 3, 2)``, ``(Q, 4, 2)``) and
    the material slot index of all its faces."""

    verts: np.ndarray
    tris: np.ndarray = field(default_factory=lambda: _NO_TRIS)
    quads: np.ndarray = field(default_factory=lambda: _NO_QUADS)
    tri_uvs: np.ndarray | None = None
    quad_uvs: np.ndarray | None = None
    material: int = 0

    @property
    def has_uvs(self) -> bool:
        return self.tri_uvs is not None or self.quad_uvs is not None

    def transformed(self, matrix: np.ndarray) -> "Part":
        """This part moved by a 4x4 affine matrix (winding reversed when the
        matrix mirrors, so normals still point out)."""
        matrix = np.asarray(matrix, dtype=np.float64)
        verts = self.verts @ matrix[:3, :3].T + matrix[:3, 3]
        moved = Part(verts, self.tris, self.quads, self.tri_uvs, self.quad_uvs, self.material)
        return moved.flipped() if np.linalg.det(matrix[:3, :3]) < 0.0 else moved

    def with_material(self, material: int) -> "Part":
        return Part(self.verts, self.tris, self.quads, self.tri_uvs, self.quad_uvs, material)

    def flipped(self) -> "Part":
        """The same part with every face wound the other way."""
        return Part(self.verts, self.tris[:, ::-1].copy(), self.quads[:, ::-1].copy(),
                    None if self.tri_uvs is None else self.tri_uvs[:, ::-1].copy(),
                    None if self.quad_uvs is None else self.quad_uvs[:, ::-1].copy(), self.material)


@dataclass
class MeshData:
    """Parts gathered into one mesh: flat loops, polygon sizes, materials, UVs."""

    parts: list = field(default_factory=list)

    def add(self, *parts: Part) -> "MeshData":
        self.parts.extend(parts)
        return self

    def arrays(self):
        """(verts (V,3) f64, loop_verts (L,) i32, poly_sizes (P,) i32,
        poly_materials (P,) i32, loop_uvs (L,2) f32 or None)."""
        verts, loops, sizes, materials, uvs = [], [], [], [], []
        offset = 0
        any_uv = any(p.has_uvs for p in self.parts)
        for part in self.parts:
            verts.append(part.verts)
            for faces, face_uvs in ((part.quads, part.quad_uvs), (part.tris, part.tri_uvs)):
                count, corners = faces.shape
                if not count:
                    continue
                loops.append((faces + offset).reshape(-1))
                sizes.append(np.full(count, corners, dtype=np.int32))
                materials.append(np.full(count, part.material, dtype=np.int32))
                if any_uv:
                    uvs.append((face_uvs if face_uvs is not None else np.zeros((count, corners, 2))).reshape(-1, 2))
            offset += len(part.verts)
        return (np.concatenate(verts).astype(np.float64),
                np.concatenate(loops).astype(np.int32),
                np.concatenate(sizes),
                np.concatenate(materials),
                np.concatenate(uvs).astype(np.float32) if any_uv else None)


# --------------------------------------------------------------------------
# Transforms

def _fans(part: Part) -> np.ndarray:
    """Every face as triangles (a, b, c), fanned from its first corner."""
    quads = part.quads
    return np.concatenate((part.tris, quads[:, (0, 1, 2)], quads[:, (0, 2, 3)]))


def signed_volume(part: Part) -> float:
    """Volume enclosed by a closed part; positive when its faces wind outward."""
    v = part.verts[_fans(part)]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def is_consistently_wound(part: Part) -> bool:
    """True when every edge of a closed part is used once in each direction."""
    edges = []
    for faces in (part.tris, part.quads):
        if len(faces):
            edges.append(np.stack((faces.reshape(-1), np.roll(faces, -1, axis=1).reshape(-1)), axis=1))
    edges = np.concatenate(edges)
    directed = set(map(tuple, edges.tolist()))
    if len(directed) != len(edges):
        return False
    return all((b, a) in directed for a, b in directed)


def orient_convex(part: Part) -> Part:
    """Flip the faces of a convex part whose normal points to its centroid."""
    centre = part.verts.mean(axis=0)

    def fix(faces, uvs):
        if not len(faces):
            return faces, uvs
        v = part.verts[faces]
        normal = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        outward = np.einsum("ij,ij->i", normal, v.mean(axis=1) - centre) >= 0.0
        faces = np.where(outward[:, None], faces, faces[:, ::-1])
        if uvs is not None:
            uvs = np.where(outward[:, None, None], uvs, uvs[:, ::-1])
        return faces, uvs

    tris, tri_uvs = fix(part.tris, part.tri_uvs)
    quads, quad_uvs = fix(part.quads, part.quad_uvs)
    return Part(part.verts, tris, quads, tri_uvs, quad_uvs, part.material)


# --------------------------------------------------------------------------
# Primitives (all closed ones wind outward)

_BOX_QUADS = np.array(((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4),
                       (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)), dtype=np.int32)


def box(lo, hi, material: int = 0, uv_scale: float | None = None) -> Part:
    """Axis-aligned box from corner ``lo`` to corner ``hi``. With ``uv_scale``
    each face gets planar UVs of ``uv_scale`` units per metre."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    verts = np.array(((x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
                      (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)), dtype=np.float64)
    uvs = None
    if uv_scale is not None:
        corners = verts[_BOX_QUADS]
        normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
        uvs = np.empty((6, 4, 2))
        for face, drop in enumerate(np.abs(normal).argmax(axis=1)):
            keep = [i for i in range(3) if i != drop]
            uvs[face] = corners[face][:, keep] * uv_scale
    return Part(verts, quads=_BOX_QUADS.copy(), quad_uvs=uvs, material=material)


def grid(x0, x1, y0, y1, nx: int, ny: int, z: float = 0.0, uv_scale: float = 1.0,
         material: int = 0) -> Part:
    """A flat grid facing +Z with UVs of ``uv_scale`` units per metre."""
    xs = np.linspace(x0, x1, nx + 1)
    ys = np.linspace(y0, y1, ny + 1)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    verts = np.stack((gx, gy, np.full_like(gx, z)), axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    a = (i * (ny + 1) + j).reshape(-1)
    quads = np.stack((a, a + ny + 1, a + ny + 2, a + 1), axis=1).astype(np.int32)
    return Part(verts, quads=quads, quad_uvs=verts[quads][:, :, :2] * uv_scale, material=material)


def _ring_quads(rings: int, segments: int) -> np.ndarray:
    """Quads between consecutive rings of ``segments`` vertices each."""
    j, i = np.meshgrid(np.arange(rings - 1), np.arange(segments), indexing="ij")
    i1 = (i + 1) % segments
    return np.stack((j * segments + i, j * segments + i1,
                     (j + 1) * segments + i1, (j + 1) * segments + i), axis=-1).reshape(-1, 4).astype(np.int32)


def _fan(centre: int, ring_start: int, segments: int, reverse: bool) -> np.ndarray:
    ring = np.arange(segments)
    a, b = ring_start + ring, ring_start + (ring + 1) % segments
    if reverse:
        a, b = b, a
    return np.stack((np.full(segments, centre), a, b), axis=1).astype(np.int32)


def revolve(radii, heights, segments: int, cap_bottom: float | None = None,
            cap_top: float | None = None, material: int = 0) -> Part:
    """Lathe a profile (radius, height), listed bottom to top, around +Z.

    ``cap_bottom``/``cap_top`` close the ends with a fan whose centre sits at
    that height (a pole for spheres, the ring's own height for a flat cap).
    """
    radii = np.asarray(radii, dtype=np.float64)
    heights = np.asarray(heights, dtype=np.float64)
    rings = len(radii)
    phi = np.linspace(0.0, 2.0 * math.pi, segments, endpoint=False)
    verts = np.empty((rings, segments, 3))
    verts[..., 0] = radii[:, None] * np.cos(phi)
    verts[..., 1] = radii[:, None] * np.sin(phi)
    verts[..., 2] = heights[:, None]
    verts = list(verts.reshape(-1, 3))
    tris = []
    if cap_bottom is not None:
        verts.append((0.0, 0.0, cap_bottom))
        tris.append(_fan(len(verts) - 1, 0, segments, reverse=True))
    if cap_top is not None:
        verts.append((0.0, 0.0, cap_top))
        tris.append(_fan(len(verts) - 1, (rings - 1) * segments, segments, reverse=False))
    return Part(np.array(verts), np.concatenate(tris) if tris else _NO_TRIS,
                _ring_quads(rings, segments), material=material)


def uv_sphere(radius: float, segments: int = 48, rings: int = 24, material: int = 0) -> Part:
    theta = np.linspace(-math.pi / 2, math.pi / 2, rings + 1)[1:-1]
    return revolve(radius * np.cos(theta), radius * np.sin(theta), segments,
                   cap_bottom=-radius, cap_top=radius, material=material)


def cylinder(radius: float, z0: float, z1: float, segments: int = 32, material: int = 0) -> Part:
    return revolve((radius, radius), (z0, z1), segments, cap_bottom=z0, cap_top=z1, material=material)


def octahedron(radius: float, material: int = 0) -> Part:
    verts = radius * np.array(((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)), float)
    tris = np.array(((0, 2, 4), (2, 1, 4), (1, 3, 4), (3, 0, 4),
                     (2, 0, 5), (1, 2, 5), (3, 1, 5), (0, 3, 5)), dtype=np.int32)
    return orient_convex(Part(verts, tris=tris, material=material))


def torus(major: float, minor: float, major_segments: int = 64, minor_segments: int = 32,
          material: int = 0) -> Part:
    """Torus around +Z."""
    u = np.linspace(0.0, 2 * math.pi, major_segments, endpoint=False)
    v = np.linspace(0.0, 2 * math.pi, minor_segments, endpoint=False)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    ring = major + minor * np.cos(vv)
    verts = np.stack((ring * np.cos(uu), ring * np.sin(uu), minor * np.sin(vv)), axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(major_segments), np.arange(minor_segments), indexing="ij")
    i1 = (i + 1) % major_segments
    j1 = (j + 1) % minor_segments
    quads = np.stack((i * minor_segments + j, i1 * minor_segments + j,
                      i1 * minor_segments + j1, i * minor_segments + j1), axis=-1).reshape(-1, 4)
    return Part(verts, quads=quads.astype(np.int32), material=material)


def arch_band(span_start: float, span_end: float, depth: float, z_spring: float, z_top: float,
              radius: float, segments: int = 24, material: int = 0) -> Part:
    """A wall band along +X from ``span_start`` to ``span_end`` (centred on
    y = 0, ``depth`` thick, from ``z_spring`` to ``z_top``) pierced by a
    semicircular arch of ``radius`` springing at ``z_spring`` mid-span."""
    mid = 0.5 * (span_start + span_end)
    half = 0.5 * (span_end - span_start)
    corner = math.atan2(z_top - z_spring, half)
    angles = np.unique(np.concatenate((np.linspace(0.0, math.pi, segments + 1),
                                       (corner, math.pi - corner))))
    cos, sin = np.cos(angles), np.sin(angles)
    cos[np.abs(cos) < 1e-12] = 0.0
    inner = np.stack((mid + radius * cos, z_spring + radius * sin), axis=1)
    with np.errstate(divide="ignore"):
        to_side = np.where(cos != 0.0, half / np.abs(cos), np.inf)
        to_top = np.where(sin > 1e-12, (z_top - z_spring) / np.maximum(sin, 1e-300), np.inf)
    reach = np.minimum(to_side, to_top)
    outer = np.stack((mid + reach * cos, z_spring + reach * sin), axis=1)
    count = len(angles)
    # Counter-clockwise boundary of the band's (x, z) section:
    # outer[0 .. n-1] (up the right side, over the top, down the left), then
    # inner[n-1 .. 0] (back along the arch).
    loop = np.concatenate((outer, inner[::-1]))
    size = 2 * count
    verts = np.concatenate((
        np.stack((loop[:, 0], np.full(size, -0.5 * depth), loop[:, 1]), axis=1),
        np.stack((loop[:, 0], np.full(size, 0.5 * depth), loop[:, 1]), axis=1)))
    outer_at = np.arange(count)
    inner_at = size - 1 - np.arange(count)
    k = np.arange(count - 1)
    front = np.stack((inner_at[k], outer_at[k], outer_at[k + 1], inner_at[k + 1]), axis=1)
    back = front[:, ::-1] + size
    here = np.arange(size)
    after = (here + 1) % size
    sides = np.stack((here, here + size, after + size, after), axis=1)
    return Part(verts, quads=np.concatenate((front, back, sides)).astype(np.int32), material=material)


def tube(points, radii, segments: int = 12, cap_start: bool = True, cap_end: bool = True,
         material: int = 0) -> Part:
    """A generalised cylinder along a polyline with a radius per point
    (parallel-transported rings, so it does not twist)."""
    points = np.asarray(points, dtype=np.float64)
    radii = np.asarray(radii, dtype=np.float64)
    count = len(points)
    tangents = np.gradient(points, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    helper = np.array((1.0, 0.0, 0.0)) if abs(tangents[0, 0]) < 0.9 else np.array((0.0, 1.0, 0.0))
    normal = helper - helper.dot(tangents[0]) * tangents[0]
    normals = np.empty_like(points)
    for index in range(count):
        t = tangents[index]
        normal = normal - normal.dot(t) * t
        normal = normal / np.linalg.norm(normal)
        normals[index] = normal
    binormals = np.cross(tangents, normals)
    phi = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    offsets = (np.cos(phi)[None, :, None] * normals[:, None, :]
               + np.sin(phi)[None, :, None] * binormals[:, None, :])
    verts = list((points[:, None, :] + radii[:, None, None] * offsets).reshape(-1, 3))
    tris = []
    if cap_start:
        verts.append(points[0])
        tris.append(_fan(len(verts) - 1, 0, segments, reverse=True))
    if cap_end:
        verts.append(points[-1])
        tris.append(_fan(len(verts) - 1, (count - 1) * segments, segments, reverse=False))
    return Part(np.array(verts), np.concatenate(tris) if tris else _NO_TRIS,
                _ring_quads(count, segments), material=material)


def leaf_cards(centres: np.ndarray, sizes: np.ndarray, rng: np.random.Generator,
               material: int = 0) -> Part:
    """One diamond-shaped quad per leaf, randomly oriented around ``centres``."""
    count = len(centres)
    normal = rng.normal(size=(count, 3))
    normal[:, 2] = np.abs(normal[:, 2]) + 0.6   # leaves face the sky more often than not
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    along = np.cross(normal, rng.normal(size=(count, 3)))
    along /= np.linalg.norm(along, axis=1, keepdims=True)
    across = np.cross(normal, along)
    length = sizes[:, None]
    verts = np.stack((centres - along * length, centres - across * length * 0.45,
                      centres + along * length, centres + across * length * 0.45), axis=1).reshape(-1, 3)
    return Part(verts, quads=np.arange(4 * count, dtype=np.int32).reshape(count, 4), material=material)


def ring_sector(inner: float, outer: float, z0: float, z1: float, angle0: float, angle1: float,
                segments: int, material: int = 0) -> Part:
    """A curved wall: the solid between radii ``inner`` and ``outer`` around
    +Z, from height ``z0`` to ``z1`` and angle ``angle0`` to ``angle1``
    (radians, counter-clockwise). A full turn gives a closed ring."""
    full = abs(angle1 - angle0) >= 2 * math.pi - 1e-9
    count = segments if full else segments + 1
    angles = np.linspace(angle0, angle1, count, endpoint=not full)
    # Section loop in (r, z), counter-clockwise seen from the -phi side.
    section = np.array(((inner, z0), (outer, z0), (outer, z1), (inner, z1)))
    c, s = np.cos(angles), np.sin(angles)
    verts = np.empty((count, 4, 3))
    verts[..., 0] = c[:, None] * section[None, :, 0]
    verts[..., 1] = s[:, None] * section[None, :, 0]
    verts[..., 2] = section[None, :, 1]
    steps = count if full else count - 1
    a = np.arange(steps)
    b = (a + 1) % count
    quads = []
    for k in range(4):
        k1 = (k + 1) % 4
        quads.append(np.stack((a * 4 + k, a * 4 + k1, b * 4 + k1, b * 4 + k), axis=1))
    if not full:
        quads.append(np.array(((3, 2, 1, 0),)))
        last = (count - 1) * 4
        quads.append(np.array(((last, last + 1, last + 2, last + 3),)))
    part = Part(verts.reshape(-1, 3), quads=np.concatenate(quads).astype(np.int32), material=material)
    return part if signed_volume(part) > 0 else part.flipped()


def ellipsoid(radii, segments: int = 32, rings: int = 16, material: int = 0) -> Part:
    return uv_sphere(1.0, segments, rings, material).transformed(scale(*radii))
