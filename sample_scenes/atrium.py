"""The ``atrium`` sample scene: PHRT's stand-in for the paper's atrium.

An outdoor garden closed by a low wall: a paved plaza around a raised pool,
four trees with thousands of leaves each (one mesh per tree), three statues
on plinths, and curved surfaces of many sizes (an exedra with its bench, a
domed rotunda, stone spheres, urns). A low sun makes long, detailed shadows.
As in the paper the candidates are the trees, the statues and the water of
the pool; the water is a tagged material (``Water``) of the ``Pool`` object.
Focus: detailed shadows.

Plan (metres, +X east, +Y north, ground at z = 0, plaza top at z = 0.03)::

    y  30 +---------------------------- gate ----------------------------+
          |                                                 rotunda      |
       13 |   urn  +--------------- plaza ----------------+  urn         |
          |        |  OAK           standing statue   young tree         |
        0 |        |  seated   [ POOL: water ]   abstract statue         |
          |        |  CYPRESS                         LINDEN             |
      -13 |        +------------------------------------------+          |
          |                       ( exedra )                             |
      -30 +--------------------------------------------------------------+
         x -30          -16              0              16             30
"""
from __future__ import annotations

import math

import numpy as np

from . import geometry as geo
from . import transforms
from . import textures
from .blender_data import SceneData, packed_image, tag
from .camera_paths import RUN_MPS, WALK_MPS, Look, PathSpec

PLAZA_X, PLAZA_Y, PLAZA_TOP = 16.0, 13.0, 0.03
POOL_X, POOL_Y = 5.0, 3.0           # inner half sizes of the basin
RIM_THICKNESS, RIM_TOP, WATER_Z = 0.4, 0.6, 0.45
ENCLOSURE = 30.0

OVER_AREA_PATH = "path3"
OVER_AREA_FRAMES = (350, 440)
OVER_AREA_ELEMENT = "Pool/Water"

SHADOWS = dict(shadows=True, reflections=False, refractions=False)
# (name, position, trunk height, trunk radius, crown centre z, crown radii, leaves, clusters, leaf size, K, Q)
TREES = (
    ("Tree_Oak", (-11.0, 5.0), 3.6, 0.45, 6.4, (4.2, 4.2, 2.7), 22000, 60, 0.13, 2.0, 1.5),
    ("Tree_Linden", (10.0, -6.0), 3.0, 0.34, 5.5, (3.2, 3.2, 2.4), 15000, 45, 0.12, 1.5, 1.2),
    ("Tree_Young", (11.0, 7.5), 2.6, 0.18, 4.4, (2.0, 2.0, 1.5), 7000, 24, 0.11, 1.0, 0.8),
    ("Tree_Cypress", (-12.0, -8.0), 1.0, 0.25, 4.9, (1.25, 1.25, 3.8), 12000, 50, 0.08, 1.0, 1.0),
)
TREE_LEAVES = {"Tree_Oak": "LeavesDark", "Tree_Linden": "LeavesLight", "Tree_Young": "LeavesLight",
               "Tree_Cypress": "LeavesCypress"}
# (name, position, plinth top, K, effects, Q)
STATUES = (
    ("Statue_Standing", (0.0, 7.0), 1.2, 1.5, SHADOWS, 1.0),
    ("Statue_Seated", (-9.0, 0.0), 1.0, 1.2, SHADOWS, 1.0),
    ("Statue_Abstract", (9.0, 0.0), 0.8, 1.0, dict(shadows=True, reflections=True, refractions=False), 1.2),
)
WATER = dict(priority=2.5, shadows=False, reflections=True, refractions=True, rt_cost=1.5)
ROTUNDA = (19.0, 17.0)
EXEDRA = (0.0, -20.0)
URNS = ((-2.6, 13.7), (2.6, 13.7), (-2.6, -13.7), (2.6, -13.7), (16.7, -2.6), (16.7, 2.6))
STONE_SPHERES = ((-15.0, -12.0), (15.0, -12.0), (-15.0, 12.0), (15.0, 12.0))


def _tree(rng: np.random.Generator, trunk_height: float, trunk_radius: float, crown_z: float,
          crown_radii, leaves: int, clusters: int, leaf_size: float) -> geo.MeshData:
    """Trunk and branches (material 0) and leaf cards in clusters (material 1),
    on the ground at x = y = 0."""
    data = geo.MeshData()
    lean = rng.normal(0.0, 0.05, 2)
    z = np.linspace(0.0, trunk_height, 8)
    trunk = np.stack((lean[0] * z, lean[1] * z, z), axis=1)
    radii = trunk_radius * (1.0 - 0.35 * z / trunk_height)
    radii[0] *= 1.45     # root flare
    data.add(geo.tube(trunk, radii, 16, cap_start=False, cap_end=True))
    crown = np.array((0.0, 0.0, crown_z))
    crown_radii = np.asarray(crown_radii)
    lowest = trunk_height * 0.85
    centres = []
    while len(centres) < clusters:
        p = rng.uniform(-1.0, 1.0, 3)
        if p @ p <= 1.0:
            c = crown + 0.8 * p * crown_radii
            if c[2] > lowest + 0.4:
                centres.append(c)
    centres = np.array(centres)
    top = trunk[-1]
    # Branches from the upper trunk out to each cluster, bending upwards.
    for c in centres:
        start = top - np.array((0.0, 0.0, rng.uniform(0.0, 0.25 * trunk_height)))
        middle = 0.5 * (start + c) + np.array((0.0, 0.0, 0.25 * np.linalg.norm(c - start)))
        t = np.linspace(0.0, 1.0, 5)[:, None]
        points = (1 - t) ** 2 * start + 2 * (1 - t) * t * middle + t ** 2 * c
        data.add(geo.tube(points, np.linspace(0.35 * trunk_radius, 0.04 * trunk_radius + 0.01, 5), 6,
                          cap_start=False, cap_end=True))
    # Leaves: balls of foliage around the cluster centres, pulled back inside the crown.
    owner = rng.integers(0, clusters, leaves)
    cluster_radius = 0.32 * crown_radii.min() + 0.25
    direction = rng.normal(size=(leaves, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    positions = centres[owner] + direction * cluster_radius * rng.random((leaves, 1)) ** 0.5
    relative = (positions - crown) / crown_radii
    outside = np.linalg.norm(relative, axis=1)
    relative /= np.maximum(outside, 1.0)[:, None]
    positions = crown + relative * crown_radii
    positions[:, 2] = np.maximum(positions[:, 2], lowest)
    sizes = leaf_size * rng.uniform(0.7, 1.3, leaves)
    data.add(geo.leaf_cards(positions, sizes, rng, material=1))
    return data


def _ellipsoid(radii, centre, tilt_deg=(0.0, 0.0, 0.0), segments=28, rings=14) -> geo.Part:
    rx, ry, rz = (math.radians(a) for a in tilt_deg)
    return geo.ellipsoid(radii, segments, rings).transformed(transforms.compose(
        transforms.translation(*centre), transforms.rotation_z(rz), transforms.rotation_y(ry), transforms.rotation_x(rx)))


def _standing_figure() -> geo.MeshData:
    """A heroic figure (2.1 m) with a raised arm, from overlapping ellipsoids."""
    parts = [
        _ellipsoid((0.11, 0.12, 0.48), (-0.12, 0.0, 0.5), (0, 4, 0)),     # legs
        _ellipsoid((0.11, 0.12, 0.48), (0.13, 0.04, 0.5), (-6, -5, 0)),
        _ellipsoid((0.08, 0.14, 0.05), (-0.13, 0.05, 0.04)),               # feet
        _ellipsoid((0.08, 0.14, 0.05), (0.16, 0.1, 0.04)),
        _ellipsoid((0.23, 0.16, 0.17), (0.0, 0.0, 1.0)),                   # hips
        _ellipsoid((0.25, 0.16, 0.34), (0.0, 0.0, 1.38)),                  # torso
        _ellipsoid((0.3, 0.15, 0.12), (0.0, 0.0, 1.62)),                   # shoulders
        _ellipsoid((0.055, 0.055, 0.08), (0.0, 0.0, 1.76)),               # neck
        _ellipsoid((0.11, 0.12, 0.14), (0.0, 0.01, 1.92)),                 # head
        _ellipsoid((0.065, 0.065, 0.3), (-0.34, 0.0, 1.38), (0, 12, 0)),   # left arm, down
        _ellipsoid((0.055, 0.055, 0.26), (-0.42, 0.05, 1.0), (12, 6, 0)),
        _ellipsoid((0.065, 0.065, 0.3), (0.38, 0.0, 1.86), (0, 30, 0)),    # right arm, raised
        _ellipsoid((0.055, 0.055, 0.26), (0.5, 0.02, 2.28), (0, 10, 0)),
        _ellipsoid((0.06, 0.05, 0.08), (0.53, 0.02, 2.56)),                # fist
    ]
    return geo.MeshData().add(*parts)


def _seated_figure() -> geo.MeshData:
    """A thinker on a block: seated, leaning forward, chin on hand."""
    parts = [
        geo.box((-0.3, -0.3, 0.0), (0.3, 0.25, 0.5)),                          # block
        _ellipsoid((0.12, 0.3, 0.11), (-0.13, 0.22, 0.6), (0, 0, 0)),          # thighs
        _ellipsoid((0.12, 0.3, 0.11), (0.13, 0.22, 0.6), (0, 0, 0)),
        _ellipsoid((0.09, 0.09, 0.27), (-0.14, 0.5, 0.3)),                     # shins
        _ellipsoid((0.09, 0.09, 0.27), (0.15, 0.52, 0.3)),
        _ellipsoid((0.22, 0.16, 0.16), (0.0, 0.0, 0.66)),                      # hips
        _ellipsoid((0.23, 0.15, 0.32), (0.0, 0.1, 0.98), (-22, 0, 0)),         # torso, leaning
        _ellipsoid((0.28, 0.15, 0.11), (0.0, 0.2, 1.2), (-22, 0, 0)),
        _ellipsoid((0.1, 0.12, 0.13), (0.02, 0.38, 1.38)),                     # head
        _ellipsoid((0.06, 0.06, 0.25), (0.28, 0.3, 1.05), (-40, 0, 0)),        # right arm to the chin
        _ellipsoid((0.05, 0.05, 0.2), (0.14, 0.42, 1.14), (50, 0, 30)),
        _ellipsoid((0.06, 0.06, 0.26), (-0.28, 0.25, 0.95), (-35, 0, 0)),     # left arm on the knee
    ]
    return geo.MeshData().add(*parts)


def _abstract_sculpture() -> geo.MeshData:
    """Stacked bronze spheres threaded through a tilted ring."""
    parts = []
    z = 0.0
    for radius in (0.5, 0.4, 0.31, 0.23, 0.16):
        parts.append(geo.uv_sphere(radius, 40, 20).transformed(transforms.translation(0.0, 0.0, z + radius * 0.9)))
        z += radius * 1.75
    parts.append(geo.torus(0.75, 0.07, 64, 16).transformed(transforms.compose(
        transforms.translation(0.0, 0.0, 1.2), transforms.rotation_y(math.radians(30)))))
    return geo.MeshData().add(*parts)


def _pool() -> geo.MeshData:
    """A raised basin: stone rim (material 0), tiled floor (1), water (2)."""
    t = RIM_THICKNESS
    data = geo.MeshData()
    data.add(geo.box((-POOL_X - t, POOL_Y, 0.0), (POOL_X + t, POOL_Y + t, RIM_TOP), 0, uv_scale=1.0),
             geo.box((-POOL_X - t, -POOL_Y - t, 0.0), (POOL_X + t, -POOL_Y, RIM_TOP), 0, uv_scale=1.0),
             geo.box((POOL_X, -POOL_Y, 0.0), (POOL_X + t, POOL_Y, RIM_TOP), 0, uv_scale=1.0),
             geo.box((-POOL_X - t, -POOL_Y, 0.0), (-POOL_X, POOL_Y, RIM_TOP), 0, uv_scale=1.0))
    data.add(geo.box((-POOL_X, -POOL_Y, 0.0), (POOL_X, POOL_Y, 0.05), 1, uv_scale=0.5))
    data.add(geo.grid(-POOL_X, POOL_X, -POOL_Y, POOL_Y, 20, 12, WATER_Z, uv_scale=0.25, material=2))
    return data


def _rotunda() -> geo.MeshData:
    """Eight columns on a round base under a ring beam and a dome."""
    data = geo.MeshData()
    data.add(geo.cylinder(3.7, 0.0, 0.35, 64))
    for k in range(8):
        angle = 2 * math.pi * k / 8
        x, y = 3.0 * math.cos(angle), 3.0 * math.sin(angle)
        z = np.linspace(0.35, 3.2, 6)
        data.add(geo.revolve(0.2 * (1.0 - 0.1 * (z - 0.35) / 2.85), z, 24, cap_bottom=0.35).transformed(
            transforms.translation(x, y, 0.0)))
        data.add(geo.revolve((0.18, 0.22, 0.27, 0.28), (3.2, 3.28, 3.36, 3.4), 24, cap_top=3.4).transformed(
            transforms.translation(x, y, 0.0)))
    data.add(geo.ring_sector(2.6, 3.5, 3.4, 3.9, 0.0, 2 * math.pi, 64))
    theta = np.linspace(0.0, math.pi / 2, 17)[:-1]
    data.add(geo.revolve(3.5 * np.cos(theta), 3.9 + 3.0 * np.sin(theta), 64, cap_bottom=3.9, cap_top=6.9))
    return data


def _exedra() -> geo.MeshData:
    """A semicircular wall opening north, with a curved bench inside it."""
    data = geo.MeshData()
    data.add(geo.ring_sector(6.75, 7.25, 0.0, 3.4, math.pi, 2 * math.pi, 96))
    data.add(geo.ring_sector(6.7, 7.35, 3.4, 3.6, math.pi, 2 * math.pi, 96))      # coping
    data.add(geo.ring_sector(5.8, 6.4, 0.0, 0.45, math.pi + 0.15, 2 * math.pi - 0.15, 64))  # bench
    for end in (-1, 1):
        data.add(geo.box((end * 7.0 - 0.35, -0.35, 0.0), (end * 7.0 + 0.35, 0.35, 3.8)))  # end piers
    return data


def _urn() -> geo.Part:
    profile = np.array(((0.25, 0.0), (0.25, 0.08), (0.12, 0.14), (0.1, 0.24), (0.2, 0.34), (0.38, 0.55),
                        (0.42, 0.72), (0.36, 0.9), (0.24, 1.0), (0.28, 1.06)))
    return geo.revolve(profile[:, 0], profile[:, 1], 40, cap_bottom=0.0, cap_top=1.0)


def _gate() -> geo.MeshData:
    """The north gate: two piers and an arch across a gap in the wall."""
    data = geo.MeshData()
    data.add(geo.box((-3.2, -0.6, 0.0), (-2.0, 0.6, 4.6)), geo.box((2.0, -0.6, 0.0), (3.2, 0.6, 4.6)))
    data.add(geo.arch_band(-2.0, 2.0, 1.0, 2.8, 4.6, 1.5, 32))
    return data


def build(data: SceneData, rng: np.random.Generator) -> None:
    """Create the atrium's objects, materials and lights in ``data.scene``."""
    mat = data.material
    grass = mat("Grass", roughness=0.95, image=packed_image("AtriumGrass", textures.grass(128, rng)))
    paving = mat("Paving", roughness=0.6, image=packed_image("AtriumPaving", textures.tiles(
        256, 4, (0.74, 0.70, 0.62), (0.62, 0.58, 0.52), (0.35, 0.33, 0.3), rng, grout_px=2)))
    pool_tiles = mat("PoolTiles", roughness=0.3, image=packed_image("AtriumPoolTiles", textures.tiles(
        256, 8, (0.20, 0.48, 0.62), (0.14, 0.38, 0.52), (0.85, 0.85, 0.82), rng, grout_px=2)))
    stone = mat("Stone", (0.72, 0.68, 0.6), roughness=0.75)
    wall_stone = mat("WallStone", (0.62, 0.52, 0.42), roughness=0.85)
    marble = mat("Marble", (0.9, 0.88, 0.84), roughness=0.3, coat=0.2)
    bronze = mat("Bronze", (0.72, 0.45, 0.22), metallic=1.0, roughness=0.3)
    terracotta = mat("Terracotta", (0.62, 0.3, 0.17), roughness=0.7)
    bark = mat("Bark", (0.23, 0.16, 0.1), roughness=0.9)
    mat("LeavesDark", (0.09, 0.25, 0.05), roughness=0.6)
    mat("LeavesLight", (0.2, 0.4, 0.08), roughness=0.6)
    mat("LeavesCypress", (0.06, 0.18, 0.07), roughness=0.6)
    water = mat("Water", (0.85, 0.95, 0.97), roughness=0.0, transmission=1.0, ior=1.33)

    data.mesh_object("Ground", geo.MeshData().add(
        geo.grid(-40.0, 40.0, -40.0, 40.0, 40, 40, 0.0, uv_scale=0.25)), [grass])
    data.mesh_object("Plaza", geo.MeshData().add(
        geo.box((-PLAZA_X, -PLAZA_Y, 0.0), (PLAZA_X, PLAZA_Y, PLAZA_TOP), uv_scale=1.0 / 3.0)), [paving])
    e, t, h = ENCLOSURE, 0.6, 2.6
    walls = geo.MeshData().add(
        geo.box((-e - t, -e - t, 0.0), (e + t, -e, h), uv_scale=0.5),
        geo.box((-e - t, -e, 0.0), (-e, e, h), uv_scale=0.5),
        geo.box((e, -e, 0.0), (e + t, e, h), uv_scale=0.5),
        geo.box((-e - t, e, 0.0), (-2.0, e + t, h), uv_scale=0.5),
        geo.box((2.0, e, 0.0), (e + t, e + t, h), uv_scale=0.5))
    data.mesh_object("EnclosureWall", walls, [wall_stone])
    data.mesh_object("Gate", _gate(), [wall_stone], location=(0.0, e + t / 2, 0.0))

    data.mesh_object("Pool", _pool(), [stone, pool_tiles, water])
    tag(water, **WATER)

    for name, (x, y), height, radius, crown_z, crown_radii, count, clusters, leaf, priority, cost in TREES:
        tree = _tree(rng, height, radius, crown_z, crown_radii, count, clusters, leaf)
        obj = data.mesh_object(name, tree, [bark, data.materials[TREE_LEAVES[name]]], location=(x, y, 0.0))
        obj.rotation_euler[2] = rng.uniform(0.0, 2 * math.pi)
        tag(obj, priority, rt_cost=cost, **SHADOWS)

    plinths = geo.MeshData()
    builders = {"Statue_Standing": (_standing_figure, marble),
                "Statue_Seated": (_seated_figure, marble),
                "Statue_Abstract": (_abstract_sculpture, bronze)}
    for name, (x, y), top, priority, effects, cost in STATUES:
        plinths.add(geo.box((x - 0.6, y - 0.6, 0.0), (x + 0.6, y + 0.6, top - 0.1), uv_scale=1.0),
                    geo.box((x - 0.68, y - 0.68, top - 0.1), (x + 0.68, y + 0.68, top), uv_scale=1.0))
        shape, material = builders[name]
        obj = data.mesh_object(name, shape(), [material], location=(x, y, top))
        tag(obj, priority, rt_cost=cost, **effects)
    # The figures face the pool.
    data.scene.objects["Statue_Standing"].rotation_euler[2] = math.pi
    data.scene.objects["Statue_Seated"].rotation_euler[2] = -math.pi / 2
    for x, y in STONE_SPHERES:
        plinths.add(geo.box((x - 0.45, y - 0.45, 0.0), (x + 0.45, y + 0.45, 0.7), uv_scale=1.0))
    data.mesh_object("Plinths", plinths, [stone])

    spheres = geo.MeshData()
    for x, y in STONE_SPHERES:
        spheres.add(geo.uv_sphere(0.6, 48, 24).transformed(transforms.translation(x, y, 1.3)))
    data.mesh_object("StoneSpheres", spheres, [stone])
    urns = geo.MeshData().add(*(_urn().transformed(transforms.translation(x, y, 0.0)) for x, y in URNS))
    data.mesh_object("Urns", urns, [terracotta])
    data.mesh_object("Rotunda", _rotunda(), [marble], location=ROTUNDA + (0.0,))
    data.mesh_object("Exedra", _exedra(), [stone], location=EXEDRA + (0.0,))

    data.sun_towards("Sun", elevation_deg=38.0, azimuth_deg=200.0, strength=4.5)
    data.sky("AtriumSky", (0.45, 0.62, 0.9), 1.0)


# Camera paths (frame numbers set against where the player is at that time).
PATHS = (
    PathSpec(
        name="path1",
        description="Walk (1.4 m/s) from the north lawn under the oak's canopy, looking up into the leaves, "
                    "past the seated statue and along the pool, looking at the water and the cypress.",
        waypoints=((-5.2, 13.6), (-6.6, 10.5), (-8.0, 7.6), (-7.4, 3.5), (-7.0, 0.0), (-6.8, -4.2),
                   (-5.0, -6.6), (-1.0, -8.0), (3.0, -8.5)),
        speeds=((1, WALK_MPS), (1000, WALK_MPS)),
        floor_z=PLAZA_TOP,
        glances=((1, 0, -4), (80, 0, -4), (120, 25, 2), (160, 0, -4), (1000, 0, -4)),
        looks=(Look(190, 400, (-10.0, 5.5, 5.5), ramp=50), Look(430, 580, (-9.0, 0.0, 1.9)),
               Look(570, 720, (-2.0, -0.5, 0.45), ramp=60), Look(700, 860, (-12.0, -8.0, 3.5), ramp=70)),
    ),
    PathSpec(
        name="path2",
        description="Run (4.5 m/s) a lap around the plaza: up the east side past the linden and the young "
                    "tree, along the north side past the standing statue (slowing to a walk to look at it), "
                    "down the west side under the oak and past the cypress, glancing at the pool so trees "
                    "and statues sweep across the view.",
        waypoints=((14.0, -10.0), (14.2, -3.0), (13.8, 4.0), (12.8, 10.8), (6.0, 11.2), (-1.0, 10.8),
                   (-8.0, 11.0), (-14.0, 9.5), (-15.2, 3.0), (-15.2, -3.0), (-15.0, -9.0), (-11.0, -12.0),
                   (-4.0, -11.5), (3.0, -10.5)),
        speeds=((1, RUN_MPS), (300, RUN_MPS), (340, WALK_MPS), (440, WALK_MPS), (480, RUN_MPS),
                (1000, RUN_MPS)),
        floor_z=PLAZA_TOP,
        glances=((1, 0, -4), (60, 0, -4), (100, 60, -6), (150, 60, -6), (190, 0, -4), (480, 0, -4),
                 (520, 55, -6), (580, 55, -6), (620, 0, -4), (700, 0, -4), (740, 60, -4), (800, 60, -4),
                 (840, 0, -4), (1000, 0, -4)),
        looks=(Look(300, 470, (0.0, 7.0, 2.3), ramp=40),),
    ),
    PathSpec(
        name="path3",
        description="Walk (1.4 m/s) from the rotunda to the pool, stop at the rim and look down into the "
                    "water (it fills over 40% of the frame), then walk along the rim and run (4.5 m/s) past "
                    "the bronze sculpture and the linden to the exedra, turning round there for a far view "
                    "back over the plaza.",
        waypoints=((4.68, 10.95), (3.6, 7.8), (1.0, 3.8), (3.5, 3.85), (5.6, 4.0), (6.8, 2.0), (6.9, -2.5),
                   (5.5, -7.5), (2.0, -12.0), (0.5, -14.5), (0.0, -16.5), (-0.3, -19.0)),
        speeds=((1, WALK_MPS), (330, WALK_MPS), (370, 0.0), (450, 0.0), (490, WALK_MPS), (580, WALK_MPS),
                (620, RUN_MPS), (900, RUN_MPS), (950, 0.0), (1000, 0.0)),
        floor_z=PLAZA_TOP,
        glances=((1, 0, -4), (100, 0, -4), (140, -35, 0), (200, -35, 0), (240, 0, -4), (910, 0, -4),
                 (1000, 170, 6)),
        looks=(Look(330, 470, (1.0, 2.0, WATER_Z), ramp=40), Look(560, 680, (9.0, 0.0, 1.6))),
    ),
)
