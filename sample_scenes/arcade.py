"""The ``arcade`` sample scene: PHRT's stand-in for the paper's sponza.

An indoor two-storey courtyard: a 24 x 9 m open floor ringed by arcades of
columns and round arches on two storeys, aisles between the arcades and the
outer walls, a tiled floor, banners hanging from the upper gallery and a
roof over the galleries only, so the sun comes in through the open middle.
As in the paper, only primitives are candidates (mirror and glass spheres,
octahedrons, cubes, a torus) plus the glass of two display cases (a tagged
material). Focus: reflection and transparency.

Plan (metres, +X east, +Y north, floor at z = 0)::

    y  8.5 +-----------------------------------------------------------+  outer wall
           |  north aisle   [vitrine]                  (small mirror)  |
       4.5 |  o  o  o  o  o  o  o  o  o     columns every 3 m           |
           |  o  octahedrons     torus  mirror cube   medium mirror  o |
       0   |  o       LARGE MIRROR          LARGE GLASS   glass cube o | (glass sphere)
           |  o                              green sphere            o |
      -4.5 |  o  o  o  o  o  o  o  o  o                                |
           |  (small glass)  south aisle       [vitrine]               |
      -8.5 +-----------------------------------------------------------+
          x -17.5        -12                    0                  12  17.5
"""
from __future__ import annotations

import math

import numpy as np

from . import geometry as geo
from . import transforms
from . import textures
from .blender_data import SceneData, packed_image, tag
from .camera_paths import RUN_MPS, WALK_MPS, Look, PathSpec

HALL_X, HALL_Y = 17.5, 8.5          # inner faces of the outer walls
WALL_THICKNESS, WALL_HEIGHT = 0.5, 10.5
COLUMN_XS = tuple(float(x) for x in range(-12, 13, 3))   # long sides, at y = +-LINE_Y
LINE_X, LINE_Y = 12.0, 4.5          # column lines of the courtyard
END_YS = (-1.5, 1.5)                # extra columns on the short sides, at x = +-LINE_X
GALLERY_Z = 5.0                     # underside of the upper gallery's floor
GALLERY_TOP = 5.3
ROOF_Z = 9.7

GROUND_STOREY = dict(base=0.0, plinth=0.8, plinth_h=0.25, radius=0.30, shaft_top=3.0,
                     capital_top=3.35, abacus=0.9, spring=3.5, band_top=GALLERY_Z)
UPPER_STOREY = dict(base=GALLERY_TOP, plinth=0.6, plinth_h=0.2, radius=0.22, shaft_top=7.9,
                    capital_top=8.15, abacus=0.65, spring=8.3, band_top=ROOF_Z)

OVER_AREA_PATH = "path2"
OVER_AREA_FRAMES = (490, 620)
OVER_AREA_ELEMENT = "MirrorSphere_Large"


def column_positions():
    positions = [(x, side * LINE_Y) for side in (-1, 1) for x in COLUMN_XS]
    positions += [(side * LINE_X, y) for side in (-1, 1) for y in END_YS]
    return positions


def _column(storey: dict, x: float, y: float) -> list:
    """Plinth, base moulding, tapered shaft, flared capital and abacus."""
    base, radius = storey["base"], storey["radius"]
    half_plinth = storey["plinth"] / 2
    shaft_bottom = base + storey["plinth_h"]
    parts = [geo.box((-half_plinth, -half_plinth, base), (half_plinth, half_plinth, shaft_bottom))]
    parts.append(geo.torus(radius * 1.1, radius * 0.2, 48, 12).transformed(
        transforms.translation(0.0, 0.0, shaft_bottom + radius * 0.15)))
    z = np.linspace(shaft_bottom, storey["shaft_top"], 9)
    taper = 1.0 - 0.12 * ((z - shaft_bottom) / (storey["shaft_top"] - shaft_bottom)) ** 1.5
    parts.append(geo.revolve(radius * taper, z, 40))
    top = storey["shaft_top"]
    cap = storey["capital_top"] - top
    parts.append(geo.revolve(radius * np.array((0.88, 0.96, 1.1, 1.33, 1.4)),
                             top + cap * np.array((0.0, 0.18, 0.45, 0.85, 1.0)), 40,
                             cap_top=storey["capital_top"]))
    half_abacus = storey["abacus"] / 2
    parts.append(geo.box((-half_abacus, -half_abacus, storey["capital_top"]),
                         (half_abacus, half_abacus, storey["spring"])))
    move = transforms.translation(x, y, 0.0)
    return [p.transformed(move) for p in parts]


def _arcade_bands(storey: dict, material: int) -> list:
    """The arch bands between neighbouring columns on all four sides."""
    depth = storey["abacus"]
    parts = []
    xs = COLUMN_XS
    for side in (-1, 1):
        for a, b in zip(xs[:-1], xs[1:]):
            band = geo.arch_band(a, b, depth, storey["spring"], storey["band_top"],
                                 (b - a - depth) / 2, 24, material)
            parts.append(band.transformed(transforms.translation(0.0, side * LINE_Y, 0.0)))
    ys = (-LINE_Y,) + END_YS + (LINE_Y,)
    for side in (-1, 1):
        for a, b in zip(ys[:-1], ys[1:]):
            band = geo.arch_band(a, b, depth, storey["spring"], storey["band_top"],
                                 (b - a - depth) / 2, 24, material)
            # band runs along +X; turn it to run along +Y at x = side * LINE_X
            parts.append(band.transformed(transforms.compose(transforms.translation(side * LINE_X, 0.0, 0.0),
                                                      transforms.rotation_z(math.pi / 2))))
    half = depth / 2
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * LINE_X, sy * LINE_Y
            parts.append(geo.box((x - half, y - half, storey["spring"]),
                                 (x + half, y + half, storey["band_top"]), material))
    return parts


def _slab_ring(z0: float, z1: float, inner_x: float, inner_y: float, material: int) -> list:
    """A floor or roof slab over the aisles, around the open courtyard."""
    return [geo.box((-HALL_X, inner_y, z0), (HALL_X, HALL_Y, z1), material, uv_scale=0.5),
            geo.box((-HALL_X, -HALL_Y, z0), (HALL_X, -inner_y, z1), material, uv_scale=0.5),
            geo.box((inner_x, -inner_y, z0), (HALL_X, inner_y, z1), material, uv_scale=0.5),
            geo.box((-HALL_X, -inner_y, z0), (-inner_x, inner_y, z1), material, uv_scale=0.5)]


def _walls() -> geo.MeshData:
    t, h = WALL_THICKNESS, WALL_HEIGHT
    data = geo.MeshData()
    data.add(geo.box((-HALL_X - t, HALL_Y, 0.0), (HALL_X + t, HALL_Y + t, h)),
             geo.box((-HALL_X - t, -HALL_Y - t, 0.0), (HALL_X + t, -HALL_Y, h)),
             geo.box((HALL_X, -HALL_Y, 0.0), (HALL_X + t, HALL_Y, h)),
             geo.box((-HALL_X - t, -HALL_Y, 0.0), (-HALL_X, HALL_Y, h)))
    # Pilasters answer the columns on the aisle walls, on both storeys.
    depth = 0.25
    for x in COLUMN_XS:
        for y0, y1 in ((HALL_Y - depth, HALL_Y), (-HALL_Y, -HALL_Y + depth)):
            data.add(geo.box((x - 0.3, y0, 0.0), (x + 0.3, y1, GALLERY_Z)),
                     geo.box((x - 0.22, y0, GALLERY_TOP), (x + 0.22, y1, ROOF_Z)))
    for y in (-LINE_Y,) + END_YS + (LINE_Y,):
        for x0, x1 in ((HALL_X - depth, HALL_X), (-HALL_X, -HALL_X + depth)):
            data.add(geo.box((x0, y - 0.3, 0.0), (x1, y + 0.3, GALLERY_Z)))
    return data


def _banner(width: float, height: float, rng: np.random.Generator) -> geo.Part:
    """A hanging cloth (in the XZ plane, facing -Y) with soft vertical folds
    and a swallow-tail hem; its top edge at z = 0."""
    nx, nz = 24, 32
    u = np.linspace(-0.5, 0.5, nx + 1)
    v = np.linspace(0.0, 1.0, nz + 1)
    uu, vv = np.meshgrid(u, v, indexing="ij")
    phase = rng.uniform(0.0, 2 * math.pi)
    fold = 0.05 * np.sin(2 * math.pi * 4 * uu + phase) * (0.3 + vv)
    hem = 0.12 * height * (1.0 - 2.0 * np.abs(uu))          # deeper in the middle: a swallow tail
    z = -vv * (height - hem)
    verts = np.stack((uu * width, fold - 0.1 * vv ** 2, z), axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nx), np.arange(nz), indexing="ij")
    a = (i * (nz + 1) + j).reshape(-1)
    quads = np.stack((a, a + 1, a + nz + 2, a + nz + 1), axis=1).astype(np.int32)
    return geo.Part(verts, quads=quads)


def _vitrine() -> geo.MeshData:
    """A wooden display stand with a glass case (material 1) and a gold goblet
    (material 2) inside; centred on x = y = 0, on the floor."""
    data = geo.MeshData()
    half_x, half_y, stand, case_top, pane = 0.8, 0.35, 0.9, 1.75, 0.012
    data.add(geo.box((-half_x, -half_y, 0.0), (half_x, half_y, stand)))
    data.add(geo.box((-half_x - 0.03, -half_y - 0.03, stand - 0.05), (half_x + 0.03, half_y + 0.03, stand)))
    glass = [geo.box((-half_x, -half_y, stand), (half_x, -half_y + pane, case_top)),
             geo.box((-half_x, half_y - pane, stand), (half_x, half_y, case_top)),
             geo.box((-half_x, -half_y + pane, stand), (-half_x + pane, half_y - pane, case_top)),
             geo.box((half_x - pane, -half_y + pane, stand), (half_x, half_y - pane, case_top)),
             geo.box((-half_x, -half_y, case_top), (half_x, half_y, case_top + pane))]
    data.add(*(g.with_material(1) for g in glass))
    goblet = geo.revolve((0.09, 0.09, 0.018, 0.018, 0.06, 0.085, 0.09),
                         (0.0, 0.012, 0.035, 0.16, 0.19, 0.27, 0.36), 32, cap_bottom=0.0, cap_top=0.34)
    data.add(goblet.transformed(transforms.translation(0.0, 0.0, stand)).with_material(2))
    return data


# Candidates: (name, kind, size, (x, y), z rotation deg, material, K, effects, Q)
# Designer's priorities: the big hero pieces in the middle of the courtyard
# matter most; the octahedron row fades out (the paper's heuristic dropped
# "the last three octahedrons"); the small pieces in the aisles matter least.
MIRROR = dict(shadows=True, reflections=True, refractions=False)
GLASS = dict(shadows=True, reflections=False, refractions=True)
CANDIDATES = (
    ("MirrorSphere_Large", "sphere", 1.2, (-5.0, -1.6), 0, "Mirror", 3.0, MIRROR, 1.0),
    ("GlassSphere_Large", "sphere", 0.9, (2.6, -2.3), 0, "Glass", 2.5, GLASS, 1.5),
    ("Torus_Mirror", "torus", 0.9, (1.0, 2.5), 35, "Mirror", 2.0, MIRROR, 1.2),
    ("MirrorSphere_Medium", "sphere", 0.7, (8.5, 2.0), 0, "Mirror", 1.5, MIRROR, 1.0),
    ("Cube_Mirror", "cube", 1.1, (5.0, 2.7), 25, "Mirror", 1.2, MIRROR, 1.0),
    ("Cube_Glass", "cube", 0.8, (10.0, -1.8), 40, "Glass", 1.0, GLASS, 1.5),
    ("GreenSphere", "sphere", 0.55, (6.2, -2.9), 0, "GreenGlass", 0.8, GLASS, 1.5),
    ("Octahedron_1", "octahedron", 0.7, (-10.2, 2.9), 10, "Mirror", 1.2, MIRROR, 1.0),
    ("Octahedron_2", "octahedron", 0.55, (-8.7, 2.9), 30, "Glass", 0.9, GLASS, 1.5),
    ("Octahedron_3", "octahedron", 0.45, (-7.4, 2.9), 50, "Mirror", 0.7, MIRROR, 1.0),
    ("Octahedron_4", "octahedron", 0.35, (-6.2, 2.9), 70, "Glass", 0.5, GLASS, 1.5),
    ("MirrorSphere_Small", "sphere", 0.45, (9.0, 7.2), 0, "Mirror", 0.8, MIRROR, 1.0),
    ("GlassSphere_Small", "sphere", 0.35, (-9.0, -7.4), 0, "Glass", 0.6, GLASS, 1.5),
    ("GlassSphere_Medium", "sphere", 0.6, (15.3, -2.6), 0, "Glass", 1.0, GLASS, 1.5),
)
# The display cases' glass is a tagged material: one element per case.
DISPLAY_GLASS = dict(priority=1.5, rt_cost=1.2, **GLASS)
VITRINES = (("Vitrine_North", (-4.5, HALL_Y - 0.65), 0.0), ("Vitrine_South", (4.5, -HALL_Y + 0.65), math.pi))


def _candidate_part(kind: str, size: float) -> geo.Part:
    """The primitive resting on the floor, centred on x = y = 0."""
    if kind == "sphere":
        return geo.uv_sphere(size, 64, 32).transformed(transforms.translation(0.0, 0.0, size))
    if kind == "torus":
        ring = geo.torus(size, 0.22, 96, 40)
        return ring.transformed(transforms.compose(transforms.translation(0.0, 0.0, size + 0.22), transforms.rotation_x(math.pi / 2)))
    if kind == "cube":
        half = size / 2
        return geo.box((-half, -half, 0.0), (half, half, size))
    if kind == "octahedron":
        return geo.octahedron(size).transformed(transforms.translation(0.0, 0.0, size))
    raise ValueError(kind)


def build(data: SceneData, rng: np.random.Generator) -> None:
    """Create the arcade's objects, materials and lights in ``data.scene``."""
    floor_image = packed_image("ArcadeFloorTiles", textures.tiles(
        256, 4, (0.80, 0.74, 0.64), (0.42, 0.30, 0.24), (0.25, 0.22, 0.2), rng))
    mat = data.material
    floor = mat("FloorTiles", roughness=0.35, image=floor_image)
    sandstone = mat("Sandstone", (0.70, 0.60, 0.47), roughness=0.8)
    marble = mat("ColumnMarble", (0.86, 0.83, 0.77), roughness=0.35)
    plaster = mat("Plaster", (0.78, 0.74, 0.68), roughness=0.9)
    wood = mat("Wood", (0.33, 0.19, 0.09), roughness=0.55)
    gold = mat("Gold", (1.0, 0.77, 0.34), metallic=1.0, roughness=0.25)
    mat("Mirror", (0.92, 0.92, 0.92), metallic=1.0, roughness=0.02)
    mat("Glass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5)
    mat("GreenGlass", (0.25, 0.85, 0.35), roughness=0.0, transmission=1.0, ior=1.45)
    display_glass = mat("DisplayGlass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5)
    banners = [mat("BannerRed", (0.55, 0.05, 0.04), roughness=0.85, sheen=0.6),
               mat("BannerBlue", (0.05, 0.11, 0.45), roughness=0.85, sheen=0.6),
               mat("BannerGreen", (0.07, 0.33, 0.11), roughness=0.85, sheen=0.6)]

    data.mesh_object("Floor", geo.MeshData().add(
        geo.grid(-HALL_X, HALL_X, -HALL_Y, HALL_Y, 35, 17, 0.0, uv_scale=1.0 / 3.0)), [floor])
    data.mesh_object("Walls", _walls(), [sandstone])

    for name, storey in (("Colonnade_Ground", GROUND_STOREY), ("Colonnade_Upper", UPPER_STOREY)):
        parts = geo.MeshData()
        for x, y in column_positions():
            parts.add(*_column(storey, x, y))
        parts.add(*_arcade_bands(storey, 1))
        data.mesh_object(name, parts, [marble, sandstone])

    gallery = geo.MeshData().add(*_slab_ring(GALLERY_Z, GALLERY_TOP, LINE_X - 0.45, LINE_Y - 0.45, 0))
    rail_half, rail_top = 0.15, GALLERY_TOP + 1.0
    for side in (-1, 1):
        y = side * LINE_Y
        gallery.add(geo.box((-LINE_X, y - rail_half, GALLERY_TOP), (LINE_X, y + rail_half, rail_top), 1),
                    geo.box((-LINE_X, y - 0.2, rail_top), (LINE_X, y + 0.2, rail_top + 0.12), 1))
        x = side * LINE_X
        gallery.add(geo.box((x - rail_half, -LINE_Y, GALLERY_TOP), (x + rail_half, LINE_Y, rail_top), 1),
                    geo.box((x - 0.2, -LINE_Y, rail_top), (x + 0.2, LINE_Y, rail_top + 0.12), 1))
    data.mesh_object("Gallery", gallery, [plaster, sandstone])
    roof = geo.MeshData().add(*_slab_ring(ROOF_Z, ROOF_Z + 0.3, LINE_X - 0.325, LINE_Y - 0.325, 0))
    data.mesh_object("Roof", roof, [plaster])

    # Banners hang from the gallery rail in front of every other ground column.
    for index, x in enumerate((-6.0, 0.0, 6.0)):
        for side in (-1, 1):
            cloth = _banner(1.3, 3.2, rng)
            facing = transforms.rotation_z(0.0 if side > 0 else math.pi)
            move = transforms.compose(transforms.translation(x, side * (LINE_Y - 0.55), rail_top + 0.05), facing)
            name = f"Banner_{'N' if side > 0 else 'S'}{index + 1}"
            data.mesh_object(name, geo.MeshData().add(cloth.transformed(move)),
                             [banners[(index + (side > 0)) % 3]])

    for name, (x, y), turn in VITRINES:
        obj = data.mesh_object(name, _vitrine(), [wood, display_glass, gold], location=(x, y, 0.0))
        obj.rotation_euler[2] = turn
    tag(display_glass, **DISPLAY_GLASS)

    for name, kind, size, (x, y), turn_deg, material, priority, effects, cost in CANDIDATES:
        obj = data.mesh_object(name, geo.MeshData().add(_candidate_part(kind, size)),
                               [data.materials[material]], location=(x, y, 0.0),
                               smooth=kind in ("sphere", "torus"))
        obj.rotation_euler[2] = math.radians(turn_deg)
        tag(obj, priority, rt_cost=cost, **effects)

    # Lights: the sun through the open roof, lamps in the aisles.
    data.sun_towards("Sun", elevation_deg=62.0, azimuth_deg=-60.0, strength=4.0)
    data.light("Lamp_North", "POINT", (-6.0, 6.7, 4.3), 500.0, (1.0, 0.82, 0.6), size=0.2)
    data.light("Lamp_South", "POINT", (6.0, -6.7, 4.3), 500.0, (1.0, 0.82, 0.6), size=0.2)
    data.light("Panel_West", "AREA", (-15.0, 0.0, 4.9), 400.0, (1.0, 0.9, 0.8), size=2.0)
    data.light("Panel_East", "AREA", (15.0, 0.0, 4.9), 400.0, (1.0, 0.9, 0.8), size=2.0)
    data.sky("ArcadeSky", (0.50, 0.62, 0.82), 0.8)


# Camera paths. Frame numbers in the looks and glances were set against
# where the player is at that time (walking 1.4 m/s covers 2.3 m per 100 frames,
# running 4.5 m/s 7.5 m).
PATHS = (
    PathSpec(
        name="path1",
        description="Walk (1.4 m/s) from the west aisle through the arcade and down the whole courtyard, "
                    "looking left at the octahedrons, right at the large mirror sphere, up at the gallery, "
                    "then at the torus and the large glass sphere as they pass.",
        waypoints=((-16.0, 0.8), (-14.0, 0.3), (-12.0, 0.0), (-10.0, 0.6), (-7.5, 1.2), (-4.5, 1.2),
                   (-2.0, 0.8), (0.5, 0.4), (3.5, 0.4), (6.5, 0.3), (9.0, 0.3), (10.5, 0.3)),
        speeds=((1, WALK_MPS), (1000, WALK_MPS)),
        glances=((1, 0, -4), (460, 0, -4), (520, 12, 24), (570, 12, 24), (620, 0, -4),
                 (880, 0, -4), (920, 35, -6), (960, 35, -6), (1000, 0, -4)),
        looks=(Look(110, 260, (-8.2, 2.9, 0.6)), Look(290, 440, (-5.0, -1.6, 1.2)),
               Look(580, 700, (1.0, 2.5, 1.1)), Look(690, 820, (2.6, -2.3, 0.9), ramp=40)),
    ),
    PathSpec(
        name="path2",
        description="Walk (1.4 m/s) along the south aisle past the small glass sphere, through the arcade "
                    "and slowly around the large mirror sphere at arm's length, looking into it (it fills "
                    "over 40% of the frame), then run (4.5 m/s) east through the courtyard into the east aisle.",
        waypoints=((-15.5, -6.5), (-12.0, -6.4), (-9.5, -6.3), (-7.8, -5.6), (-7.5, -4.5), (-7.4, -3.4),
                   (-6.93, -2.30), (-7.02, -1.0), (-6.4, -0.05), (-5.3, 0.45), (-4.0, 0.45),
                   (-1.5, 0.3), (2.0, 0.2), (5.5, 0.0), (8.0, 0.1), (10.3, 0.2),
                   (12.0, 0.0), (14.0, 0.3), (15.3, 2.0), (15.2, 5.5), (12.0, 6.5), (6.0, 6.3)),
        speeds=((1, WALK_MPS), (440, WALK_MPS), (470, 1.1), (640, 1.1), (700, RUN_MPS), (1000, RUN_MPS)),
        glances=((1, 0, -4), (120, 0, -4), (170, 40, -2), (230, 40, -2), (280, 0, -4), (840, 0, -4),
                 (870, -45, -6), (910, -45, -6), (950, 0, -4), (1000, 0, -4)),
        looks=(Look(380, 660, (-5.0, -1.6, 1.1), ramp=40),),
    ),
    PathSpec(
        name="path3",
        description="Run (4.5 m/s) the loop of aisles: up the east aisle, west along the north aisle "
                    "glancing left through the arches so the candidates sweep across the view, down the "
                    "west aisle and east along the south aisle, then walk into the courtyard between the "
                    "large mirror and glass spheres and look around.",
        waypoints=((14.0, -6.0), (13.8, 0.0), (14.6, 5.4), (12.0, 6.4), (6.0, 6.2), (0.0, 6.4),
                   (-6.0, 6.4), (-12.0, 6.4), (-15.0, 5.2), (-15.3, 0.0), (-15.0, -5.0), (-12.0, -6.3),
                   (-6.0, -6.4), (-2.5, -6.1), (-1.5, -4.5), (-1.3, -2.0), (-1.0, -0.5), (-0.5, 1.0)),
        speeds=((1, RUN_MPS), (885, RUN_MPS), (925, WALK_MPS), (975, 0.3), (1000, 0.0)),
        glances=((1, 0, -4), (150, 0, -4), (200, 50, -6), (260, 50, -6), (300, 0, -4), (330, 55, -6),
                 (420, 55, -6), (460, 0, -4), (640, 0, -4), (700, 50, -6), (760, 50, -6), (800, 0, -4),
                 (930, 0, -4), (960, 50, 0), (1000, -30, 4)),
    ),
)
