"""Scene snapshot: everything a PHRT frame needs, as plain Python and numpy.

The engine turns a Blender depsgraph into a ``SceneSnapshot`` (``engine/extract.py``);
every later stage (raster, selection, trace, composite, logs) reads only this.
Data flows one way: depsgraph -> snapshot -> G-buffer -> selection -> trace ->
composite.

Conventions
- World space is Blender's (Z up, metres). Matrices are float64 4x4, column
  vectors (``p_world = matrix_world @ p_local``).
- Geometry is triangles. Each mesh instance keeps its *local* vertices and its
  world matrix, so a moving object does not change its geometry key and static
  geometry is uploaded once per replay (GPU batches and the Embree scene).
- Element indices refer to ``SceneSnapshot.elements``; ``-1`` means "not part of
  any element". Material indices refer to ``SceneSnapshot.materials``.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field

import numpy as np

from .. import defaults, schema
from . import rules


@dataclass
class Material:
    """Principled-BSDF parameters PHRT shades with (raster and tracer alike)."""

    name: str
    base_color: tuple = (0.8, 0.8, 0.8)
    metallic: float = 0.0
    roughness: float = 0.5
    transmission: float = 0.0
    ior: float = 1.5
    alpha: float = 1.0
    emission: tuple = (0.0, 0.0, 0.0)  # colour * strength, linear
    # Optional base-colour texture: (h, w, 4) float32 linear RGBA, row 0 at the
    # bottom (Blender's pixel order), sampled with the mesh's active UV map
    # (``rules.prepare_texture`` / ``rules.sample_texture``).
    texture: np.ndarray | None = None
    texture_key: str | None = None

    @property
    def is_transparent(self) -> bool:
        """Drawn in the transparent layer (``rules.is_transparent``)."""
        return rules.is_transparent(self)

    @property
    def casts_shadow(self) -> bool:
        """Occludes light in shadow maps and for shadow rays (``rules.casts_shadow``)."""
        return rules.casts_shadow(self)


@dataclass
class Element:
    """A ray tracing element: a whole object or one material's faces of an object."""

    name: str
    object_name: str
    material_name: str | None = None
    candidate: bool = True
    priority: float = 1.0  # K
    rt_cost: float = 1.0  # Q
    shadows: bool = True
    reflections: bool = True
    refractions: bool = True

    @property
    def is_candidate(self) -> bool:
        """Tagged with K > 0 (``rules.is_candidate``)."""
        return rules.is_candidate(self)


@dataclass
class MeshInstance:
    """One drawn object (or instance): local triangles and a world matrix."""

    name: str
    matrix_world: np.ndarray  # (4, 4) float64
    positions: np.ndarray  # (V, 3) float32, local space
    triangles: np.ndarray  # (T, 3) int32 indices into positions
    corner_normals: np.ndarray  # (T*3, 3) float32, local space, one per triangle corner
    corner_uvs: np.ndarray | None  # (T*3, 2) float32 or None
    tri_material: np.ndarray  # (T,) int32 index into SceneSnapshot.materials
    tri_element: np.ndarray  # (T,) int32 index into SceneSnapshot.elements, or -1
    geometry_key: str = ""

    def __post_init__(self):
        if not self.geometry_key:
            self.geometry_key = geometry_key(self.positions, self.triangles, self.tri_material, self.tri_element)

    @property
    def n_triangles(self) -> int:
        return int(self.triangles.shape[0])

    def world_positions(self) -> np.ndarray:
        """(V, 3) float64 world-space vertex positions."""
        return transform_points(self.matrix_world, self.positions)

    def material_groups(self):
        """[(material_index, element_index, triangle_indices)] sorted by (material, element).

        The raster pass draws one batch per group with constant material and
        element, so no per-vertex ids are needed."""
        if self.n_triangles == 0:
            return []
        keys = self.tri_material.astype(np.int64) * (1 << 32) + (self.tri_element.astype(np.int64) + 1)
        order = np.argsort(keys, kind="stable")
        sorted_keys = keys[order]
        starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1]])
        ends = np.r_[starts[1:], len(order)]
        groups = []
        for start, end in zip(starts, ends):
            key = int(sorted_keys[start])
            groups.append((key >> 32, (key & 0xFFFFFFFF) - 1, order[start:end]))
        return groups


@dataclass
class Light:
    """A light source. ``color`` is linear RGB times strength:
    watts for POINT/SPOT/AREA (Cycles' convention), W/m^2 (irradiance) for SUN."""

    name: str
    kind: str  # Blender's light type: "SUN", "POINT", "SPOT", "AREA" (lights.LightKind)
    color: tuple
    position: tuple = (0.0, 0.0, 0.0)
    direction: tuple = (0.0, 0.0, -1.0)  # direction the light travels (the lamp's -Z)
    spot_size: float = np.pi / 4  # full cone angle, radians
    spot_blend: float = 0.15
    radius: float = 0.0  # soft size (unused by hard shadows, kept for reports)
    cast_shadows: bool = True


@dataclass
class Camera:
    """The view: world matrix (camera looks down its -Z) and projection to clip space."""

    matrix_world: np.ndarray
    projection: np.ndarray
    width: int
    height: int
    ortho: bool = False
    clip_start: float = 0.1
    clip_end: float = 1000.0

    @property
    def position(self) -> np.ndarray:
        return np.asarray(self.matrix_world, dtype=np.float64)[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        forward = -np.asarray(self.matrix_world, dtype=np.float64)[:3, 2]
        return forward / max(np.linalg.norm(forward), 1e-300)

    @property
    def view_matrix(self) -> np.ndarray:
        return np.linalg.inv(np.asarray(self.matrix_world, dtype=np.float64))

    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray]:
        """Origins and unit directions (float64, (h, w, 3), row 0 = bottom) through pixel centres."""
        w, h = self.width, self.height
        xs = (np.arange(w) + 0.5) / w * 2.0 - 1.0
        ys = (np.arange(h) + 0.5) / h * 2.0 - 1.0
        ndc_x, ndc_y = np.meshgrid(xs, ys)
        inv = np.linalg.inv(np.asarray(self.projection, dtype=np.float64) @ self.view_matrix)

        def unproject(z):
            clip = np.stack([ndc_x, ndc_y, np.full_like(ndc_x, z), np.ones_like(ndc_x)], axis=-1)
            world = clip @ inv.T
            return world[..., :3] / world[..., 3:4]

        near, far = unproject(-1.0), unproject(1.0)
        direction = far - near
        direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
        return near, direction


@dataclass
class Settings:
    """Scene.phrt, copied into the snapshot."""

    mode: str = schema.HYBRID
    budget_ms: float = defaults.BUDGET_MS
    selection_weight: float = defaults.SELECTION_WEIGHT
    max_area_fraction: float = defaults.MAX_AREA_FRACTION
    max_bounces: int = defaults.MAX_BOUNCES
    cost_mode: str = "MEASURED"
    shadow_map_size: int = defaults.SHADOW_MAP_SIZE
    budget_at: float | None = None  # set: the budget is this fraction of the way from raster to ray traced
    relevance: str = "PAPER"  # 'PAPER' (equation 3) or 'ERROR' (V x expected benefit, see heuristic.py)
    selection_order: str = "RELEVANCE"  # 'RELEVANCE' (the paper's) or 'RELEVANCE_PER_MS'
    selection: str = "PAPER"  # 'PAPER' (heuristic.py) or 'BENEFIT' (select/benefit_selection.py)
    quality_tiers: bool = False  # BENEFIT may trace an item at half or quarter rate (issue 23)


@dataclass
class SceneSnapshot:
    meshes: list
    materials: list
    elements: list
    lights: list
    camera: Camera
    world_color: tuple = (0.05, 0.05, 0.05)
    settings: Settings = field(default_factory=Settings)
    frame: int = 1
    problems: list = field(default_factory=list)  # human-readable, one per skipped/approximated thing

    @property
    def n_triangles(self) -> int:
        return sum(m.n_triangles for m in self.meshes)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World-space (min, max) of all geometry; a unit box around the origin when empty."""
        lows, highs = [], []
        for mesh in self.meshes:
            if len(mesh.positions):
                world = mesh.world_positions()
                lows.append(world.min(axis=0))
                highs.append(world.max(axis=0))
        if not lows:
            return -np.ones(3), np.ones(3)
        return np.min(lows, axis=0), np.max(highs, axis=0)

    def candidate_mask(self) -> np.ndarray:
        """Elements that are candidates (tagged, K > 0: ``rules.is_candidate``)."""
        return np.array([e.is_candidate for e in self.elements], dtype=bool)


def transform_points(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    matrix = np.asarray(matrix, dtype=np.float64)
    return np.asarray(points, dtype=np.float64) @ matrix[:3, :3].T + matrix[:3, 3]


def box_corners(low, high) -> np.ndarray:
    """(..., 8, 3) float64 corners of the boxes ``low``/``high`` (..., 3): bit k of the corner
    index picks low (0) or high (1) on axis k."""
    low = np.asarray(low, dtype=np.float64)[..., None, :]
    high = np.asarray(high, dtype=np.float64)[..., None, :]
    return np.where(_CORNER_PICK == 1, high, low)


_CORNER_PICK = (np.arange(8)[:, None] >> np.arange(3)[None, :]) & 1  # (8, 3)


def normal_matrix(matrix: np.ndarray) -> np.ndarray:
    """Inverse-transpose of the upper 3x3 (normals under non-uniform scale); safe for singular matrices."""
    upper = np.asarray(matrix, dtype=np.float64)[:3, :3]
    try:
        return np.linalg.inv(upper).T
    except np.linalg.LinAlgError:
        return upper


def geometry_key(*arrays) -> str:
    """A content hash of arrays: equal geometry gives the same key across frames and runs."""
    digest = hashlib.blake2b(digest_size=16)
    for array in arrays:
        array = np.ascontiguousarray(array)
        digest.update(str(array.shape).encode())
        digest.update(array.tobytes())
    return digest.hexdigest()
