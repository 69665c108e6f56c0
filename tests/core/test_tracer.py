"""The Embree tracer (phrt_addon/trace/tracer.py) on hand-built scenes: Snell refraction
through a slab, total internal reflection, mirror reflection, shadows without
acne or leaks from 1e-3 to 1e5 world units and at grazing angles, static and
dynamic geometry, thread-pool parity, and no NaN/Inf.  No bpy: snapshots are
built with numpy and drive TraceScene / RadianceTracer directly."""
import numpy as np
import pytest

from phrt.phrt_addon.scene import shading
from phrt.phrt_addon.raster import shadowmap
from phrt.phrt_addon.trace import embree_scene
from phrt.phrt_addon.scene.snapshot import Camera, Element, Light, Material, MeshInstance, SceneSnapshot, Settings
from phrt.phrt_addon.trace.tracer import RadianceTracer
from phrt.phrt_addon.trace.embree_scene import TraceScene

BLACK = (0.0, 0.0, 0.0)


# -- hand-built scenes ---------------------------------------------------------------

def mesh(name, positions, triangles, normals, material=0, element=-1, matrix=None):
    positions = np.asarray(positions, np.float32)
    triangles = np.asarray(triangles, np.int32).reshape(-1, 3)
    normals = np.asarray(normals, np.float32).reshape(-1, 3)
    if len(normals) == len(triangles):  # flat: one normal per triangle
        normals = np.repeat(normals, 3, axis=0)
    count = len(triangles)
    return MeshInstance(name=name, matrix_world=np.eye(4) if matrix is None else np.asarray(matrix, float),
                        positions=positions, triangles=triangles, corner_normals=normals, corner_uvs=None,
                        tri_material=np.full(count, material, np.int32), tri_element=np.full(count, element, np.int32))


def quad(name, centre, size_x, size_y, normal="+z", material=0, element=-1):
    """An axis-aligned rectangle in the plane through ``centre`` facing ``normal`` (+z, -z, +x, -x, +y, -y)."""
    axis = "xyz".index(normal[1])
    sign = 1.0 if normal[0] == "+" else -1.0
    u_axis, v_axis = [a for a in range(3) if a != axis]
    corners = np.zeros((4, 3))
    for index, (a, b) in enumerate(((-1, -1), (1, -1), (1, 1), (-1, 1))):
        corners[index, u_axis] = a * size_x / 2.0
        corners[index, v_axis] = b * size_y / 2.0
    corners += np.asarray(centre, float)
    n = np.zeros(3)
    n[axis] = sign
    return mesh(name, corners, [[0, 1, 2], [0, 2, 3]], [n, n], material, element)


def box(name, low, high, material=0, element=-1):
    """A closed axis-aligned box, 12 triangles, outward normals."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    corners = np.array([[x, y, z] for x in (low[0], high[0]) for y in (low[1], high[1]) for z in (low[2], high[2])])
    faces = []  # (vertex indices of the face in order, normal)
    for axis in range(3):
        for side in (0, 1):
            ids = [i for i in range(8) if ((i >> (2 - axis)) & 1) == side]
            centre = corners[ids].mean(axis=0)
            # Order the four corners around the face centre.
            u_axis, v_axis = [a for a in range(3) if a != axis]
            angles = np.arctan2(corners[ids, v_axis] - centre[v_axis], corners[ids, u_axis] - centre[u_axis])
            ids = [ids[i] for i in np.argsort(angles)]
            normal = np.zeros(3)
            normal[axis] = 1.0 if side else -1.0
            faces.append((ids, normal))
    triangles, normals = [], []
    for ids, normal in faces:
        triangles += [[ids[0], ids[1], ids[2]], [ids[0], ids[2], ids[3]]]
        normals += [normal, normal]
    return mesh(name, corners, triangles, normals, material, element)


def uv_sphere(name, centre, radius, segments=96, rings=48, material=0, element=-1):
    """A smooth UV sphere (per-corner normals = radial directions)."""
    theta = np.linspace(0.0, np.pi, rings + 1)
    phi = np.linspace(0.0, 2 * np.pi, segments + 1)[:-1]
    t, p = np.meshgrid(theta, phi, indexing="ij")
    unit_points = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    triangles = []
    for ring in range(rings):
        for segment in range(segments):
            a = ring * segments + segment
            b = ring * segments + (segment + 1) % segments
            c, d = a + segments, b + segments
            triangles += [[a, c, d], [a, d, b]]
    triangles = np.array(triangles)
    # Drop the degenerate triangles at the poles.
    area = np.linalg.norm(np.cross(unit_points[triangles[:, 1]] - unit_points[triangles[:, 0]],
                                   unit_points[triangles[:, 2]] - unit_points[triangles[:, 0]]), axis=1)
    triangles = triangles[area > 1e-12]
    normals = unit_points[triangles.ravel()]
    return mesh(name, np.asarray(centre) + radius * unit_points, triangles, normals, material, element)


def translation(offset):
    matrix = np.eye(4)
    matrix[:3, 3] = offset
    return matrix


def snapshot(meshes, materials, lights=(), world=BLACK, max_bounces=4):
    camera = Camera(matrix_world=np.eye(4), projection=np.eye(4), width=4, height=4)
    n_elements = 1 + max([int(m.tri_element.max()) for m in meshes] + [-1])
    elements = [Element(name=f"e{i}", object_name=f"e{i}") for i in range(n_elements)]
    return SceneSnapshot(meshes=list(meshes), materials=list(materials), elements=elements, lights=list(lights),
                         camera=camera, world_color=world, settings=Settings(max_bounces=max_bounces))


def build(snap, threads=1):
    scene = TraceScene(threads=threads)
    scene.update(snap)
    return scene, RadianceTracer(scene, snap, shading.MaterialTable(snap.materials))


def emissive(name, color):
    return Material(name, base_color=BLACK, roughness=1.0, emission=color)


def diffuse(name, color=(0.5, 0.5, 0.5)):
    return Material(name, base_color=color, roughness=1.0)


GLASS = Material("glass", base_color=(1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.5)
MIRROR = Material("mirror", base_color=(1.0, 1.0, 1.0), metallic=1.0, roughness=0.0)


# -- refraction: Snell's law through a slab -----------------------------------------------

SLAB_IOR = 1.5
SLAB_THICKNESS = 1.0
FLOOR_GAP = 0.5


def slab_displacement(theta, thickness=SLAB_THICKNESS, ior=SLAB_IOR):
    """Lateral shift of a ray crossing a parallel slab at incidence ``theta``: d (tan(theta) - tan(theta_t))."""
    theta_t = np.arcsin(np.sin(theta) / ior)
    return thickness * (np.tan(theta) - np.tan(theta_t))


@pytest.mark.parametrize("degrees", [10.0, 30.0, 50.0, 70.0])
def test_ray_through_a_glass_slab_lands_where_snell_law_says(degrees, closing):
    """A ray enters a slab (top z = 1, bottom z = 0) at ``theta`` and lands on an emissive floor
    (z = -0.5): a narrow green stripe around the predicted point, red everywhere else."""
    theta = np.radians(degrees)
    straight = (SLAB_THICKNESS + FLOOR_GAP) * np.tan(theta)  # where the unbent ray would land
    predicted = straight - slab_displacement(theta)
    half_width = 0.005
    assert slab_displacement(theta) > 10 * half_width  # the test can tell bent from straight
    floor_z = -FLOOR_GAP
    materials = [GLASS, emissive("red", (1.0, 0.0, 0.0)), emissive("green", (0.0, 1.0, 0.0))]
    meshes = [
        box("slab", (-20, -20, 0.0), (20, 20, SLAB_THICKNESS), material=0),
        quad("stripe", (predicted, 0, floor_z), 2 * half_width, 40, material=2),
        quad("left", (predicted - half_width - 10, 0, floor_z), 20, 40, material=1),
        quad("right", (predicted + half_width + 10, 0, floor_z), 20, 40, material=1),
    ]
    snap = snapshot(meshes, materials)
    scene, radiance_tracer = build(snap)
    closing(scene)
    # Start 2 units above the top face, aimed at (0, 0, top).
    direction = np.array([[np.sin(theta), 0.0, -np.cos(theta)]])
    start = np.array([[0.0, 0.0, SLAB_THICKNESS]]) - 2.0 * direction
    color = radiance_tracer.radiance(scene.to_trace(start), direction, 0)[0]
    # Transmitted through two surfaces: (1 - F)^2 of the green stripe, no red.
    fresnel = shading.fresnel_dielectric(np.array([np.cos(theta)]), SLAB_IOR)[0]
    assert color[1] > 0.9 * (1 - fresnel) ** 2
    assert color[0] < 0.05 * color[1]


def test_slab_shift_matches_snell_law_within_a_hundredth_of_the_thickness(closing):
    """Where the emergent ray lands, measured by bisection over a red/green split floor."""
    theta = np.radians(40.0)
    straight = (SLAB_THICKNESS + FLOOR_GAP) * np.tan(theta)
    predicted = straight - slab_displacement(theta)

    def greenish(split):
        materials = [GLASS, emissive("red", (1.0, 0.0, 0.0)), emissive("green", (0.0, 1.0, 0.0))]
        meshes = [box("slab", (-20, -20, 0.0), (20, 20, SLAB_THICKNESS), material=0),
                  quad("low", (split - 10, 0, -FLOOR_GAP), 20, 40, material=2),
                  quad("high", (split + 10, 0, -FLOOR_GAP), 20, 40, material=1)]
        scene, radiance_tracer = build(snapshot(meshes, materials))
        try:
            direction = np.array([[np.sin(theta), 0.0, -np.cos(theta)]])
            start = np.array([[0.0, 0.0, SLAB_THICKNESS]]) - 2.0 * direction
            color = radiance_tracer.radiance(scene.to_trace(start), direction, 0)[0]
        finally:
            scene.close()
        return color[1] > color[0]  # green: the ray landed below the split

    low, high = 0.0, straight
    assert greenish(high) and not greenish(low)
    for _ in range(14):
        middle = 0.5 * (low + high)
        low, high = (low, middle) if greenish(middle) else (middle, high)
    assert abs(0.5 * (low + high) - predicted) < 0.01 * SLAB_THICKNESS


def tir_scene():
    """Glass/air boundary (a single quad at z = 0, glass below) between a green floor (z = -1,
    inside) and a red ceiling (z = +1, outside)."""
    materials = [GLASS, emissive("red", (1.0, 0.0, 0.0)), emissive("green", (0.0, 1.0, 0.0))]
    meshes = [quad("surface", (0, 0, 0), 200, 200, "+z", material=0),
              quad("ceiling", (0, 0, 1), 200, 200, "-z", material=1),
              quad("floor", (0, 0, -1), 200, 200, "+z", material=2)]
    return snapshot(meshes, materials)


def test_ray_inside_glass_at_grazing_angle_is_totally_reflected(closing):
    scene, radiance_tracer = build(tir_scene())
    closing(scene)
    critical = np.degrees(np.arcsin(1.0 / SLAB_IOR))
    degrees = np.array([critical + 1.0, 60.0, 80.0, 88.0])
    theta = np.radians(degrees)
    directions = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)
    starts = np.tile([[0.0, 0.0, -0.5]], (len(theta), 1))
    color = radiance_tracer.radiance(scene.to_trace(starts), directions, 0)
    np.testing.assert_allclose(color[:, 0], 0.0, atol=1e-9)  # nothing escapes to the red ceiling
    np.testing.assert_allclose(color[:, 1], 1.0, rtol=1e-6)  # all of it comes back from the green floor


def test_ray_inside_glass_below_the_critical_angle_escapes(closing):
    scene, radiance_tracer = build(tir_scene())
    closing(scene)
    theta = np.radians([0.0, 20.0, 35.0])
    directions = np.stack([np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)
    starts = np.tile([[0.0, 0.0, -0.5]], (len(theta), 1))
    color = radiance_tracer.radiance(scene.to_trace(starts), directions, 0)
    fresnel = shading.fresnel_dielectric(np.cos(theta), 1.0 / SLAB_IOR)
    np.testing.assert_allclose(color[:, 0], 1.0 - fresnel, rtol=1e-4)
    np.testing.assert_allclose(color[:, 1], fresnel, rtol=1e-4, atol=1e-6)


# -- reflection ----------------------------------------------------------------------------------

def test_mirror_reflects_what_the_mirror_direction_hits(closing):
    """A mirror floor under a red square ceiling patch: rays whose reflection hits the patch see red."""
    materials = [MIRROR, emissive("red", (1.0, 0.0, 0.0))]
    meshes = [quad("mirror", (0, 0, 0), 40, 40, "+z", material=0),
              quad("patch", (2.0, 0.0, 1.0), 1.0, 1.0, "-z", material=1)]
    scene, radiance_tracer = build(snapshot(meshes, materials))
    closing(scene)
    eye = np.array([-2.0, 0.0, 1.0])
    # Floor points from x = -1 to 1.5: the reflected ray from eye via (x, y, 0) reaches z = 1 at x' = 2x + 2.
    xs = np.linspace(-1.0, 1.5, 501)
    targets = np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], axis=1)
    directions = shading.normalize(targets - eye)
    color = radiance_tracer.radiance(scene.to_trace(np.tile(eye, (len(xs), 1))), directions, 0)
    landing = 2 * xs + 2.0
    inside = np.abs(landing - 2.0) < 0.5 - 1e-3
    outside = np.abs(landing - 2.0) > 0.5 + 1e-3
    assert inside.sum() > 80
    assert np.all(color[inside, 0] > 0.9)
    assert np.all(color[outside, 0] < 1e-6)


def test_reflections_stop_at_max_bounces(closing):
    """Two parallel mirrors: the bounce recursion ends and returns the world colour."""
    materials = [MIRROR]
    meshes = [quad("a", (0, 0, 0), 10, 10, "+z"), quad("b", (0, 0, 1), 10, 10, "-z")]
    snap = snapshot(meshes, materials, world=(0.25, 0.5, 1.0), max_bounces=3)
    scene, radiance_tracer = build(snap)
    closing(scene)
    color = radiance_tracer.radiance(scene.to_trace([[0.0, 0.0, 0.5]]), np.array([[0.0, 0.0, 1.0]]), 0)
    assert np.all(np.isfinite(color))
    # depth 0, 1, 2 bounce; the hit at depth 3 may not: a chain of 4 hits then the world.
    assert radiance_tracer.rays == 4
    np.testing.assert_allclose(color[0], [0.25, 0.5, 1.0], rtol=1e-6)


def test_a_path_too_faint_to_show_is_not_traced_further(closing, monkeypatch):
    """Two parallel glossy dielectric plates (about 4% reflected at normal incidence): the second
    reflection's path weighs 0.04^2 < PATH_CUTOFF, so it is not traced and brings the world
    colour back instead; the radiance differs from tracing every bounce by under PATH_CUTOFF x
    the world colour.  Mirrors (weight 1) bounce to max_bounces as before (test above)."""
    from phrt.phrt_addon.trace import tracer as tracer_module
    cutoff = tracer_module.PATH_CUTOFF
    glossy = Material("glossy", base_color=(0.9, 0.2, 0.1), roughness=0.0)
    meshes = [quad("a", (0, 0, 0), 10, 10, "+z"), quad("b", (0, 0, 1), 10, 10, "-z")]
    snap = snapshot(meshes, [glossy], world=(0.25, 0.5, 1.0), max_bounces=8)
    origins, directions = [[0.0, 0.0, 0.5]], np.array([[0.0, 0.0, 1.0]])
    scene, cut = build(snap)
    closing(scene)
    faint = cut.radiance(scene.to_trace(origins), directions, 0)
    monkeypatch.setattr(tracer_module, "PATH_CUTOFF", 0.0)
    scene, every = build(snap)
    closing(scene)
    full = every.radiance(scene.to_trace(origins), directions, 0)
    assert every.rays == 9 and cut.rays == 2
    assert np.all(np.abs(faint - full) <= cutoff * 1.0)  # the world colour's largest channel: 1
    assert np.any(np.abs(faint - full) > 0)  # the cut paths did change something (below the bound)


# -- shadows: acne, leaks, scale --------------------------------------------------------------------

SCALES = [(1e-3, 0.0), (1.0, 0.0), (1e3, 0.0), (1e5, 0.0), (1.0, 1e5), (1e-3, 1e3)]
SUN_DIRECTION = shading.normalize(np.array([-1.0, -0.3, -1.0]))  # travelling towards -x, down


def shadow_scene(scale, offset):
    """A floor (z = 0, 6 x 6) with a hollow closed unit box standing on it, scaled by ``scale``
    and moved by ``offset`` along x, y, z; a sun from +x.  Diffuse grey, black world."""
    shift = np.array([offset, offset, offset])
    # Local float32 vertices and a float64 world matrix, as the engine's snapshots have them.
    floor = quad("floor", (0, 0, 0), 6 * scale, 6 * scale, "+z", material=0)
    cube = box("box", scale * np.array([-0.5, -0.5, 0.0]), scale * np.array([0.5, 0.5, 1.0]), material=0)
    for instance in (floor, cube):
        instance.matrix_world = translation(shift)
    sun = Light("sun", "SUN", (1.0, 1.0, 1.0), direction=tuple(SUN_DIRECTION))
    return snapshot([floor, cube], [diffuse("grey")], [sun]), shift


def segment_crosses_box(starts, directions, max_t, low, high):
    """Analytic slab test: does start + t * direction, 0 < t < max_t, pass through the box?"""
    starts, directions = np.broadcast_arrays(np.asarray(starts, float), np.asarray(directions, float))
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (np.asarray(low) - starts) / directions
        t1 = (np.asarray(high) - starts) / directions
    near = np.max(np.nan_to_num(np.minimum(t0, t1), nan=-np.inf), axis=1)
    far = np.min(np.nan_to_num(np.maximum(t0, t1), nan=np.inf), axis=1)
    return (far > np.maximum(near, 0.0)) & (near < max_t)


def in_box_shadow(points_unit):
    """Analytic: does the ray from a point (unit-scale coordinates) towards the sun cross the box?"""
    return segment_crosses_box(points_unit, -SUN_DIRECTION, np.inf, [-0.5, -0.5, 0.0], [0.5, 0.5, 1.0])


@pytest.mark.parametrize("scale,offset", SCALES)
def test_floor_shadow_has_no_acne_and_matches_the_box_silhouette(scale, offset, closing):
    snap, shift = shadow_scene(scale, offset)
    scene, radiance_tracer = build(snap, threads=2)
    closing(scene)
    rng = np.random.default_rng(1)
    # Floor points outside the box footprint, seen from a camera above; positions come from the
    # hits (float32 t along the view ray), as in a real frame.
    unit_points = np.c_[rng.uniform(-2.9, 2.9, (6000, 2)), np.zeros(6000)]
    unit_points = unit_points[np.max(np.abs(unit_points[:, :2]), axis=1) > 0.5 + 1e-3]
    eye_unit = np.array([-3.0, -2.5, 4.0])  # on the shadow's side
    # Only floor points the eye sees (not hidden behind the box, with a margin).
    hidden = segment_crosses_box(eye_unit[None, :], unit_points - eye_unit, 1.0, [-0.51, -0.51, -0.01],
                                 [0.51, 0.51, 1.01])
    unit_points = unit_points[~hidden]
    world_points = shift + scale * unit_points
    eye = shift + scale * eye_unit
    directions = shading.normalize(world_points - eye)
    color = radiance_tracer.radiance(scene.to_trace(np.tile(eye, (len(directions), 1))), directions, 0)
    assert np.all(np.isfinite(color))
    expected_lit = 0.5 / np.pi * (-SUN_DIRECTION[2])
    shadowed = in_box_shadow(unit_points)
    # Exclude points within 1e-3 (relative) of the shadow outline.
    sure = in_box_shadow(unit_points + [1e-3, 0, 0]) == shadowed
    sure &= in_box_shadow(unit_points - [1e-3, 0, 0]) == shadowed
    sure &= in_box_shadow(unit_points + [0, 1e-3, 0]) == shadowed
    sure &= in_box_shadow(unit_points - [0, 1e-3, 0]) == shadowed
    assert shadowed[sure].sum() > 150 and (~shadowed[sure]).sum() > 3000
    lit_fraction = color[:, 0] / expected_lit
    # Acne: every unshadowed floor point gets the full sun (within the BRDF's Fresnel/specular).
    acne = (~shadowed & sure) & (lit_fraction < 0.8)
    assert not np.any(acne), f"{acne.sum()} self-shadowed floor points at scale {scale}, offset {offset}"
    # The shadow is where the box says.
    leaks = (shadowed & sure) & (lit_fraction > 1e-6)
    assert not np.any(leaks), f"{leaks.sum()} lit points inside the box's shadow"


@pytest.mark.parametrize("scale,offset", SCALES)
def test_closed_box_does_not_leak_light(scale, offset, closing):
    """Looking around from inside the box (standing on the floor, its bottom coplanar with it):
    every wall, the ceiling and the floor inside are black under the sun outside."""
    snap, shift = shadow_scene(scale, offset)
    scene, radiance_tracer = build(snap, threads=2)
    closing(scene)
    rng = np.random.default_rng(2)
    directions = shading.normalize(rng.normal(size=(20000, 3)))
    # Eyes all over the inside, including 1e-4 (relative) from the walls, floor and ceiling.
    eyes_unit = rng.uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 1.0], (20000, 3))
    eyes_unit = np.clip(eyes_unit, [-0.4999, -0.4999, 1e-4], [0.4999, 0.4999, 0.9999])
    eyes = shift + scale * eyes_unit
    color = radiance_tracer.radiance(scene.to_trace(eyes), directions, 0)
    assert radiance_tracer.rays == len(directions)
    assert np.all(np.isfinite(color))
    leaking = np.flatnonzero(color.max(axis=1) > 0)
    assert len(leaking) == 0, f"{len(leaking)} of {len(color)} rays see light inside a closed box " \
                              f"(scale {scale}, offset {offset})"


@pytest.mark.parametrize("scale,offset", [(1.0, 0.0), (1e3, 0.0), (1.0, 1e5)])
def test_grazing_sun_on_an_empty_floor_lights_every_point(scale, offset, closing):
    """No caster: at 89 degrees sun incidence and a view ray 2 degrees above the floor,
    no floor point shadows itself."""
    shift = np.array([offset, offset, 0.0])
    floor = quad("floor", (0, 0, 0), 2000 * scale, 2000 * scale, "+z")
    floor.matrix_world = translation(shift)
    sun_direction = shading.normalize(np.array([np.sin(np.radians(89.0)), 0.0, -np.cos(np.radians(89.0))]))
    sun = Light("sun", "SUN", (1.0, 1.0, 1.0), direction=tuple(sun_direction))
    snap = snapshot([floor], [diffuse("grey")], [sun])
    scene, radiance_tracer = build(snap, threads=2)
    closing(scene)
    distances = np.linspace(1.0, 500.0, 5000) * scale
    azimuth = np.linspace(-np.pi, np.pi, len(distances))
    elevation = np.radians(2.0)
    directions = np.stack([np.cos(azimuth) * np.cos(elevation), np.sin(azimuth) * np.cos(elevation),
                           -np.full_like(azimuth, np.sin(elevation))], axis=1)
    eyes = shift + np.c_[np.zeros((len(distances), 2)), distances * np.tan(elevation)]
    color = radiance_tracer.radiance(scene.to_trace(eyes), directions, 0)
    assert np.all(np.isfinite(color))
    assert np.all(color[:, 0] > 0), f"{np.sum(color[:, 0] <= 0)} floor points self-shadowed at grazing light"


@pytest.mark.parametrize("distance", [1e2, 1e3, 1e4])
def test_floor_seen_from_far_away_has_no_acne(distance, closing):
    """A 2-unit floor seen from ``distance`` units (a telephoto view): the hit points carry the
    float32 error of the ray length, far above the scene's own precision."""
    sun = Light("sun", "SUN", (1.0, 1.0, 1.0), direction=tuple(shading.normalize(np.array([0.3, 0.2, -1.0]))))
    snap = snapshot([quad("floor", (0, 0, 0), 2.0, 2.0, "+z")], [diffuse("grey")], [sun])
    scene, radiance_tracer = build(snap, threads=2)
    closing(scene)
    rng = np.random.default_rng(6)
    targets = np.c_[rng.uniform(-0.9, 0.9, (20000, 2)), np.zeros(20000)]
    eye = distance * shading.normalize(np.array([1.0, -2.0, 1.5]))
    directions = shading.normalize(targets - eye)
    color = radiance_tracer.radiance(scene.to_trace(np.tile(eye, (len(targets), 1))), directions, 0)
    dark = np.sum(color[:, 0] <= 0)
    assert dark == 0, f"{dark} of {len(targets)} floor points self-shadowed seen from {distance:g} units"


def test_grazing_mirror_reflection_does_not_hit_its_own_surface(closing):
    materials = [MIRROR, emissive("sky", (0.0, 0.0, 1.0))]
    meshes = [quad("mirror", (0, 0, 0), 2000, 2000, "+z", material=0),
              quad("sky", (0, 0, 50), 1e6, 1e6, "-z", material=1)]
    scene, radiance_tracer = build(snapshot(meshes, materials))
    closing(scene)
    elevation = np.radians(np.linspace(0.05, 5.0, 200))
    directions = np.stack([np.cos(elevation), np.zeros_like(elevation), -np.sin(elevation)], axis=1)
    eyes = np.c_[np.zeros((len(elevation), 2)), 10.0 * np.sin(elevation)]  # 10 units from the hit point
    color = radiance_tracer.radiance(scene.to_trace(eyes), directions, 0)
    assert np.all(color[:, 2] > 0.9)


def test_point_light_is_not_shadowed_by_geometry_behind_it(closing):
    """The shadow ray stops at the light: a wall behind the lamp casts nothing."""
    materials = [diffuse("grey")]
    meshes = [quad("floor", (0, 0, 0), 10, 10, "+z"), quad("wall", (0, 0, 3.0), 10, 10, "-z")]
    lamp = Light("lamp", "POINT", (100.0, 100.0, 100.0), position=(0.0, 0.0, 2.0))
    scene, radiance_tracer = build(snapshot(meshes, materials, [lamp]))
    closing(scene)
    points = scene.to_trace([[0.5, 0.0, 0.0], [-1.0, 1.0, 0.0]])
    samples = shading.SurfaceSamples(position=points, normal=np.tile([0.0, 0.0, 1.0], (2, 1)),
                                     view=np.tile([0.0, 0.0, 1.0], (2, 1)), albedo=np.full((2, 3), 0.5),
                                     metallic=np.zeros(2), roughness=np.ones(2), transmission=np.zeros(2),
                                     ior=np.full(2, 1.5), emission=np.zeros((2, 3)))
    light = radiance_tracer.direct(points, samples)
    assert np.all(light[:, 0] > 0)
    occluder = scene.occluded(points + [0, 0, 1e-4], np.tile([0.0, 0.0, 1.0], (2, 1)), np.array([2.9, 3.1]))
    np.testing.assert_array_equal(occluder, [False, True])


# -- scene management, threads, robustness -----------------------------------------------------

def test_moved_object_is_traced_where_it_is_now(closing):
    materials = [diffuse("grey")]
    floor = quad("floor", (0, 0, 0), 10, 10, "+z")
    lid = quad("lid", (0, 0, 1.0), 1, 1, "-z")
    scene = TraceScene(threads=1)
    closing(scene)
    scene.update(snapshot([floor, lid], materials))
    up = np.array([[0.0, 0.0, 0.5]])
    assert scene.intersect(scene.to_trace(up), np.array([[0.0, 0.0, 1.0]]))["t"][0] == pytest.approx(0.5, rel=1e-5)
    moved = quad("lid", (0, 0, 1.0), 1, 1, "-z")
    moved.matrix_world = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 2.0], [0, 0, 0, 1]], float)
    scene.update(snapshot([floor, moved], materials))
    assert scene.intersect(scene.to_trace(up), np.array([[0.0, 0.0, 1.0]]))["t"][0] == pytest.approx(2.5, rel=1e-5)
    assert scene.stats["dynamic_triangles"] == 2
    # Removed: nothing above any more.
    scene.update(snapshot([floor], materials))
    assert np.isinf(scene.intersect(scene.to_trace(up), np.array([[0.0, 0.0, 1.0]]))["t"][0])


def test_trace_scene_starts_over_when_the_whole_scene_is_replaced(closing):
    """Another file with the same object names far away (1e5): no shadow acne from a stale origin."""
    scene, _ = build(shadow_scene(1.0, 0.0)[0], threads=1)
    closing(scene)
    snap, shift = shadow_scene(1.0, 1e5)
    scene.update(snap)
    np.testing.assert_allclose(scene.origin, shift + [0.0, 0.0, 0.5])
    assert scene.stats["dynamic_triangles"] == 0  # all of it is static again
    radiance_tracer = RadianceTracer(scene, snap, shading.MaterialTable(snap.materials))
    points = shift + np.c_[np.linspace(1.0, 2.9, 500), np.linspace(-2.9, 2.9, 500), np.zeros(500)]
    eye = shift + np.array([2.0, 0.0, 3.0])
    color = radiance_tracer.radiance(scene.to_trace(np.tile(eye, (500, 1))), shading.normalize(points - eye), 0)
    assert np.all(color[:, 0] > 0.8 * 0.5 / np.pi * -SUN_DIRECTION[2])


def test_glass_does_not_cast_shadows_but_is_hit_by_radiance_rays(closing):
    materials = [diffuse("grey"), GLASS]
    meshes = [quad("floor", (0, 0, 0), 10, 10, "+z", material=0), box("glass", (-1, -1, 1), (1, 1, 2), material=1)]
    scene, _ = build(snapshot(meshes, materials))
    closing(scene)
    start = scene.to_trace([[0.0, 0.0, 0.01]])
    assert not scene.occluded(start, np.array([[0.0, 0.0, 1.0]]), np.array([1e30]))[0]
    hits = scene.intersect(start, np.array([[0.0, 0.0, 1.0]]))
    assert hits["t"][0] == pytest.approx(0.99, rel=1e-4)
    _, material, *_ = scene.hit_surfaces(hits, np.isfinite(hits["t"]))
    assert material[0] == 1


def test_thread_pool_gives_the_same_answers_as_one_thread(closing):
    materials = [diffuse("grey"), MIRROR]
    meshes = [quad("floor", (0, 0, 0), 20, 20, "+z"), uv_sphere("ball", (0, 0, 1), 1.0, material=1)]
    snap = snapshot(meshes, materials, [Light("sun", "SUN", (1, 1, 1), direction=(0.3, 0.2, -1.0))])
    single, single_tracer = build(snap, threads=1)
    pooled, pooled_tracer = build(snap, threads=2)
    closing(single)
    closing(pooled)
    rng = np.random.default_rng(3)
    n = 3 * embree_scene.PARALLEL_CHUNK + 123  # several chunks and a remainder
    origins = rng.uniform([-5, -5, 0.5], [5, 5, 4], (n, 3))
    directions = shading.normalize(rng.normal(size=(n, 3)))
    distances = rng.uniform(0.1, 10.0, n)
    np.testing.assert_array_equal(single.occluded(single.to_trace(origins), directions, distances),
                                  pooled.occluded(pooled.to_trace(origins), directions, distances))
    a = single.intersect(single.to_trace(origins), directions)
    b = pooled.intersect(pooled.to_trace(origins), directions)
    np.testing.assert_array_equal(a["t"], b["t"])
    np.testing.assert_array_equal(a["prim"], b["prim"])
    np.testing.assert_array_equal(single_tracer.radiance(single.to_trace(origins), directions, 0),
                                  pooled_tracer.radiance(pooled.to_trace(origins), directions, 0))


def test_degenerate_input_never_produces_nan(closing):
    """Zero-area triangles, zero-length normals, zero and NaN ray directions, an empty scene."""
    materials = [diffuse("grey"), GLASS, MIRROR]
    flat = mesh("flat", [[0, 0, 0], [1, 0, 0], [2, 0, 0]], [[0, 1, 2]], [[0, 0, 0]], material=0)
    glass = box("glass", (-1, -1, 0.5), (1, 1, 1.5), material=1)
    zero_normals = quad("mirror", (0, 0, -1), 4, 4, "+z", material=2)
    zero_normals.corner_normals[:] = 0.0
    lamp = Light("lamp", "POINT", (1e4, 1e4, 1e4), position=(0.0, 0.0, 0.5))  # on the glass' bottom face
    snap = snapshot([flat, glass, zero_normals], materials, [lamp], world=(0.1, 0.1, 0.1))
    scene, radiance_tracer = build(snap)
    closing(scene)
    rng = np.random.default_rng(4)
    directions = shading.normalize(rng.normal(size=(2000, 3)))
    directions[:10] = 0.0
    directions[10:20] = np.nan
    origins = scene.to_trace(rng.uniform(-2, 2, (2000, 3)))
    color = radiance_tracer.radiance(origins, directions, 0)
    assert np.all(np.isfinite(color)) and np.all(color >= 0)
    empty = TraceScene(threads=1)
    closing(empty)
    empty.update(snapshot([], [diffuse("grey")]))
    empty_tracer = RadianceTracer(empty, snapshot([], [diffuse("grey")], world=(0.2, 0.2, 0.2)),
                                  shading.MaterialTable([diffuse("grey")]))
    np.testing.assert_allclose(empty_tracer.radiance(origins[:5], directions[20:25], 0), 0.2)
    assert not np.any(empty.occluded(origins[:5], directions[20:25], np.ones(5)))


def test_ray_epsilon_scales_with_magnitude_and_scene_size():
    small = embree_scene.ray_epsilon(np.array([[1e-3, 0.0, 0.0]]), 1e-3)[0]
    large = embree_scene.ray_epsilon(np.array([[1e5, 0.0, 0.0]]), 1e5)[0]
    # Several float32 ulps of the coordinate, far below the scene's size.
    assert 4 * np.spacing(np.float32(1e-3)) < small < 1e-3 * 1e-3
    assert 4 * np.spacing(np.float32(1e5)) < large < 1e-3 * 1e5


# -- raster shadow maps against traced shadows ------------------------------------------------------

def raycast_shadow_maps(snap, light, size):
    """The depth maps ``engine/gpu/shadow_maps.py`` draws on the GPU, made by tracing one ray per texel
    centre through the same light views (window depth, row 0 at the bottom)."""
    scene = TraceScene(threads=1)
    try:
        scene.update(snap)
        maps = []
        for view in shadowmap.light_views(light, snap.bounds(), size):
            centres = (np.arange(view.size) + 0.5) / view.size * 2.0 - 1.0
            x, y = np.meshgrid(centres, centres)
            inverse = np.linalg.inv(view.view_proj_relative)

            def unproject(z):
                clip = np.stack([x, y, np.full_like(x, z), np.ones_like(x)], axis=-1).reshape(-1, 4) @ inverse.T
                return clip[:, :3] / clip[:, 3:4]

            near, far = unproject(-1.0), unproject(1.0)
            directions = shading.normalize(far - near)
            t = scene.intersect(scene.to_trace(near + view.origin), directions)["t"]
            points = near + directions * np.where(np.isfinite(t), t, 0.0)[:, None]
            clip = np.c_[points, np.ones(len(points))] @ view.view_proj_relative.T
            depth = np.where(np.isfinite(t), clip[:, 2] / clip[:, 3] * 0.5 + 0.5, 1.0)
            maps.append(shadowmap.ShadowMap(view=view, depth=depth.reshape(view.size, view.size).astype(np.float32)))
        return maps
    finally:
        scene.close()


LIGHTS = {
    "sun": Light("sun", "SUN", (1.0, 1.0, 1.0), direction=tuple(shading.normalize(np.array([0.4, 0.3, -1.0])))),
    "spot": Light("spot", "SPOT", (500.0, 500.0, 500.0), position=(-1.0, -1.5, 5.0),
                  direction=tuple(shading.normalize(np.array([0.2, 0.3, -1.0]))), spot_size=np.radians(100.0)),
    "point": Light("point", "POINT", (500.0, 500.0, 500.0), position=(0.5, -0.5, 3.0)),
}


@pytest.mark.parametrize("kind", sorted(LIGHTS))
def test_shadow_map_lookup_agrees_with_traced_shadows_away_from_edges(kind, closing):
    light = LIGHTS[kind]
    meshes = [quad("floor", (0, 0, 0), 12, 12, "+z"), box("block", (-0.6, -0.4, 0.0), (0.4, 0.6, 1.2)),
              uv_sphere("ball", (1.8, 1.2, 0.8), 0.5, 32, 16), box("post", (-2.0, 1.5, 0.0), (-1.9, 1.6, 2.0))]
    snap = snapshot(meshes, [diffuse("grey")], [light])
    maps = raycast_shadow_maps(snap, light, 512)
    scene, _ = build(snap)
    closing(scene)
    rng = np.random.default_rng(5)
    points = np.c_[rng.uniform(-5.5, 5.5, (20000, 2)), np.zeros(20000)]
    normals = np.tile([0.0, 0.0, 1.0], (len(points), 1))

    def traced_lit(world):
        trace = scene.to_trace(world)
        direction, distance, _ = shading.light_incidence(light, trace, scene.origin)
        eps = embree_scene.ray_epsilon(trace, scene.extent)
        return ~scene.occluded(trace + normals[: len(trace)] * eps[:, None], direction, distance - 2 * eps)

    lit = traced_lit(points)
    texel = 3.0 * max(m.view.texel_angle * (1.0 if m.view.ortho else 8.0) for m in maps)
    sure = np.ones(len(points), bool)
    for offset in ([1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]):
        sure &= traced_lit(points + texel * np.array(offset, float)) == lit
    visibility = shadowmap.shadow_visibility(maps, points, normals)
    assert (~lit & sure).sum() > 200
    agree = np.mean((visibility[sure] > 0.5) == lit[sure])
    assert agree > 0.995, f"{kind}: shadow map and tracer agree on {agree:.2%} of the floor away from edges"
