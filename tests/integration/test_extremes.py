"""Extreme cases rendered through Blender with the real engine, GPU raster and Embree.  Every
frame's passes and logs are checked finite (phrt_render.render), and each case checks the one
thing that could go wrong in it:

- camera: inside a candidate, an element touching it, one straddling the near plane;
- coordinates near 1e5 with millimetre objects in one scene (the same picture as at the origin);
- degenerate meshes: zero-area triangles, duplicated vertices, flipped normals, no faces, a single
  triangle;
- optics: a clear glass sphere in a uniform world (total internal reflection at its rim: it must
  vanish), a mirror seen at 89.9 degrees, an IOR above the clamp;
- lights: none, 64, one inside a closed box, zero and 1e9 strength;
- the budget: 0 ms, 1e9 ms and one animated to change every frame, through a replay.
The 2-million-triangle mesh and the 1000-frame replay are in ``make soak`` (tools/soak.py)."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import bmesh  # noqa: E402

from phrt.engine import final, session  # noqa: E402
from phrt.engine.runs import replay  # noqa: E402
from phrt.phrt_addon.scene import rules  # noqa: E402
from phrt.phrt_addon.runs import run_files
from phrt.sample_scenes import showcase  # noqa: E402
from phrt_render import MODES, camera_rays, render, selected_elements, set_world  # noqa: E402

WIDTH, HEIGHT = 96, 72


@pytest.fixture(autouse=True)
def fresh(blender):
    final.release_caches()
    yield
    final.release_caches()


def rows_by_element():
    return {row["element"]: row for row in session.last_frame().rows}


def small_scene(world=(0.05, 0.06, 0.08)):
    scene = showcase.empty_scene(WIDTH, HEIGHT)
    scene.phrt.shadow_map_size = 256
    set_world(scene, world)
    return scene


# -- camera ------------------------------------------------------------------------------------------

def test_camera_inside_a_candidate_and_elements_at_the_near_plane(tmp_path):
    scene = small_scene()
    showcase.mesh_object("Floor", showcase.plane(10.0), showcase.principled("Floor", (0.6, 0.6, 0.6)))
    glass = showcase.principled("Glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.5)
    mirror = showcase.principled("Mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
    eye = (0.0, -3.0, 1.0)
    objects = [
        showcase.mesh_object("AroundCamera", showcase.cube(0.3), glass, location=eye),
        # A mirror strip just below the eye from behind the camera, through the near plane, ahead.
        showcase.mesh_object("ThroughNearPlane", showcase.plane(0.6), mirror, location=(0.0, -2.9, 0.97),
                             scale=(1.0, 2.0, 1.0)),
        # A cube whose front face is 0.1 mm before the eye (clipped): its inside is seen, nearer
        # than the far side of the glass box around the camera.
        showcase.mesh_object("Touching", showcase.cube(0.1), mirror, location=(0.03, -3.0 + 0.0501, 1.0)),
    ]
    for obj in objects:
        showcase.tag(obj, shadows=True, reflections=True, refractions=True)
    showcase.add_light("POINT", eye, 100.0, name="HeadLamp")  # a light at the eye, inside the box
    showcase.add_light("SUN", (0, 0, 5), 2.0, rotation=(np.radians(30), 0.0, 0.0), name="Sun")
    camera = showcase.add_camera(eye, (0.0, 0.0, 0.5))
    for mode in MODES:
        passes = render(scene, mode, "near", tmp_path)
        rows = rows_by_element()
        near = camera.data.clip_start
        for name in ("AroundCamera", "ThroughNearPlane", "Touching"):
            assert rows[name]["visible"], name
            assert rows[name]["D"] >= near * (1 - 1e-6), (name, rows[name]["D"])
        # Wherever nothing is nearer, the box around the camera is seen: every pixel has an element.
        assert sum(row["A"] for row in rows.values()) == pytest.approx(1.0)
        if mode == "RAYTRACE":
            assert {"AroundCamera", "ThroughNearPlane", "Touching"} <= selected_elements()
        assert passes["Combined"][..., :3].max() > 0


# -- 1e5 with millimetre objects ----------------------------------------------------------------------

def millimetre_scene(offset):
    """One mesh object at ``offset`` (exact in float32) holding a 4 cm floor, a 4 mm mirror ball
    and a 3 mm red cube (local coordinates, so their sizes are exact at any offset); the camera
    2.5 cm away at offsets that are exact float32 steps at 1e5 (multiples of 2^-7)."""
    scene = small_scene()
    floor = showcase.principled("Floor", (0.6, 0.6, 0.6), roughness=0.9)
    red = showcase.principled("Red", (0.8, 0.05, 0.05), roughness=0.6, emission=((1.0, 0.0, 0.0), 0.5))
    mirror = showcase.principled("Mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
    showcase.tag(mirror, shadows=True, reflections=True, refractions=False)
    showcase.tag(red, shadows=True, reflections=False, refractions=False)

    def build(bm):
        bmesh.ops.create_grid(bm, x_segments=8, y_segments=8, size=0.02)
        ball = bmesh.ops.create_uvsphere(bm, u_segments=48, v_segments=24, radius=0.004)
        bmesh.ops.translate(bm, vec=(0.0, 0.0, 0.004), verts=ball["verts"])
        for face in {f for v in ball["verts"] for f in v.link_faces}:
            face.material_index = 1
            face.smooth = True
        cube = bmesh.ops.create_cube(bm, size=0.003)
        bmesh.ops.translate(bm, vec=(0.0075, 0.004, 0.0015), verts=cube["verts"])
        for face in {f for v in cube["verts"] for f in v.link_faces}:
            face.material_index = 2

    obj = showcase.mesh_object("Level", build, floor, location=(offset, offset, offset))
    obj.data.materials.append(mirror)
    obj.data.materials.append(red)
    sun = showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(np.radians(35), 0.0, np.radians(-40)), name="Sun")
    sun.data.angle = 0.0
    camera = showcase.add_camera((offset - 0.0078125, offset - 0.0234375, offset + 0.0078125),
                                 (offset, offset, offset + 0.003), lens=35.0)
    camera.data.clip_start = 1e-4
    camera.data.clip_end = 10.0
    return scene


def test_millimetre_objects_at_1e5_render_as_at_the_origin(tmp_path):
    """No acne, no leaks, reflections in place: the frames at 1e5 match those at the origin."""
    images = {}
    for offset in (0.0, 1e5):
        scene = millimetre_scene(offset)
        for mode in ("RASTER", "RAYTRACE"):
            images[offset, mode] = render(scene, mode, f"mm-{offset:g}", tmp_path)["Combined"][..., :3]
        assert {"Level/Mirror", "Level/Red"} <= selected_elements()
        final.release_caches()
    for mode in ("RASTER", "RAYTRACE"):
        near, far = images[0.0, mode], images[1e5, mode]
        difference = np.abs(near - far).max(axis=-1)
        assert np.mean(difference < 0.02 + 0.02 * near.max(axis=-1)) > 0.99, (mode, difference.max())
    traced = images[0.0, "RAYTRACE"]
    red = (traced[..., 0] > 0.1) & (traced[..., 0] > 3 * traced[..., 1])
    far_red = (images[1e5, "RAYTRACE"][..., 0] > 0.1) & (images[1e5, "RAYTRACE"][..., 0] > 3 *
                                                           images[1e5, "RAYTRACE"][..., 1])
    assert red.sum() > 40 and np.mean(red == far_red) > 0.995  # the cube and its reflection, in place


# -- degenerate meshes -----------------------------------------------------------------------------

def from_arrays(name, vertices, faces, material, location=(0, 0, 0)):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(v) for v in vertices], [], [tuple(f) for f in faces])
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    if material is not None:
        mesh.materials.append(material)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def degenerate_scene(flip_mirror=False):
    scene = small_scene()
    showcase.mesh_object("Floor", showcase.plane(10.0), showcase.principled("Floor", (0.6, 0.6, 0.6)))
    grey = showcase.principled("Grey", (0.5, 0.5, 0.5))
    mirror = showcase.principled("Mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.05)
    objects = [
        # Zero-area triangles: collinear and repeated points, with one proper face.
        from_arrays("ZeroArea", [(0, 0, 0), (0.5, 0, 0), (1, 0, 0), (0, 0, 0.5), (0, 0, 0.5)],
                    [(0, 1, 2), (0, 3, 4), (0, 2, 3)], grey, location=(-1.5, 0.5, 0.2)),
        # Duplicated vertices: two coincident quads on unmerged vertices.
        from_arrays("Duplicated", [(0, 0, 0), (0.6, 0, 0), (0.6, 0, 0.6), (0, 0, 0.6)] * 2,
                    [(0, 1, 2, 3), (4, 5, 6, 7)], grey, location=(-0.8, 0.2, 0.1)),
        from_arrays("NoFaces", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], grey, location=(0, 0, 0.5)),
        from_arrays("OneTriangle", [(0, 0, 0), (0.8, 0, 0), (0.4, 0, 0.7)], [(0, 1, 2)], grey,
                    location=(0.8, 0.3, 0.05)),
    ]
    cube = showcase.mesh_object("MirrorCube", showcase.cube(0.6), mirror, location=(0.0, 0.8, 0.3),
                                rotation=(0.0, 0.0, 0.5))
    if flip_mirror:
        cube.data.flip_normals()
    objects.append(cube)
    for obj in objects:
        showcase.tag(obj, shadows=True, reflections=True, refractions=True)
    showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(np.radians(40), 0.0, np.radians(20)), name="Sun")
    showcase.add_light("POINT", (1.0, -1.0, 1.5), 80.0, name="Lamp")
    showcase.add_camera((0.5, -4.0, 2.0), (0.0, 0.3, 0.3), lens=35.0)
    return scene


def test_degenerate_meshes_render_finite_frames_in_every_mode(tmp_path):
    scene = degenerate_scene()
    for mode in MODES:
        passes = render(scene, mode, "degenerate", tmp_path)
        rows = rows_by_element()
        assert rows["OneTriangle"]["visible"] and rows["ZeroArea"]["visible"] and rows["Duplicated"]["visible"]
        assert "NoFaces" not in rows or not rows["NoFaces"]["visible"]
        assert passes["PHRT Candidate"].sum() > 50
    assert {"OneTriangle", "ZeroArea", "Duplicated", "MirrorCube"} <= selected_elements()


def test_flipped_normals_change_nothing(tmp_path):
    """Faces turned inside out are shaded from the side the camera (or the ray) sees them."""
    images = {}
    for flip in (False, True):
        scene = degenerate_scene(flip_mirror=flip)
        for mode in ("RASTER", "RAYTRACE"):
            images[flip, mode] = render(scene, mode, f"flip-{flip}", tmp_path)["Combined"][..., :3]
        final.release_caches()
    for mode in ("RASTER", "RAYTRACE"):
        difference = np.abs(images[True, mode] - images[False, mode]).max(axis=-1)
        assert np.mean(difference < 0.01) > 0.995, (mode, difference.max())


# -- optics -------------------------------------------------------------------------------------------

@pytest.mark.parametrize("max_bounces", [1, 8])
def test_clear_glass_sphere_vanishes_in_a_uniform_world_even_at_its_rim(max_bounces, tmp_path):
    """No lights, a uniform world: Fresnel, refraction and total internal reflection at the rim
    only move light around, raster and traced alike; the frame is the world colour everywhere."""
    world = (0.3, 0.45, 0.6)
    scene = small_scene(world)
    scene.phrt.max_bounces = max_bounces
    ball = showcase.mesh_object("Ball", showcase.sphere(1.0, 64, 32), showcase.principled(
        "Glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.5), smooth=True)
    showcase.tag(ball, shadows=False, reflections=True, refractions=True)
    showcase.add_camera((0.0, -3.5, 0.0), (0.0, 0.0, 0.0), lens=50.0)
    for mode in ("RASTER", "RAYTRACE"):
        passes = render(scene, mode, f"furnace-{max_bounces}", tmp_path)
        on_ball = passes["PHRT Candidate"] > 0.5
        assert on_ball.sum() > 0.3 * on_ball.size
        np.testing.assert_allclose(passes["Combined"][..., :3], np.broadcast_to(world, (HEIGHT, WIDTH, 3)),
                                   rtol=2e-4, atol=1e-5)
    assert session.last_frame().stats["refraction_rays"] > 0


@pytest.mark.parametrize("elevation_degrees", [0.1, 1.0])
def test_a_mirror_seen_at_89_9_degrees_reflects_the_sky(elevation_degrees, tmp_path):
    """A mirror floor and a camera 0.1 degrees above it: the mirror shows the world colour (metal
    F = 1), never itself (dark) and nothing from below."""
    world = (0.2, 0.4, 0.9)
    scene = small_scene(world)
    height = 0.01
    mirror = showcase.mesh_object("Mirror", showcase.plane(2000.0), showcase.principled(
        "Mirror", (1.0, 1.0, 1.0), metallic=1.0, roughness=0.0))
    showcase.tag(mirror, shadows=False, reflections=True, refractions=False)
    distance = height / np.tan(np.radians(elevation_degrees))
    camera = showcase.add_camera((0.0, 0.0, height), (0.0, distance, 0.0), lens=50.0)
    camera.data.clip_end = 10 * distance
    passes = render(scene, "RAYTRACE", f"grazing-{elevation_degrees}", tmp_path)
    assert "Mirror" in selected_elements()
    on_mirror = passes["PHRT Selected"] > 0.5
    assert on_mirror.sum() > 0.2 * on_mirror.size
    colour = passes["Combined"][..., :3][on_mirror]
    np.testing.assert_allclose(colour, np.broadcast_to(world, colour.shape), rtol=0.02)


def test_an_ior_above_the_clamp_renders_like_the_clamp(tmp_path):
    images = []
    for ior in (rules.MAX_IOR, 12.0):
        scene = small_scene()
        showcase.mesh_object("Floor", showcase.plane(8.0), showcase.principled("Floor", (0.7, 0.6, 0.5)))
        ball = showcase.mesh_object("Ball", showcase.sphere(0.6, 32, 16), showcase.principled(
            "Dense", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=ior), location=(0, 0, 0.6), smooth=True)
        showcase.tag(ball, shadows=False, reflections=True, refractions=True)
        showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(np.radians(30), 0.0, 0.3), name="Sun")
        showcase.add_camera((0.0, -3.0, 1.5), (0.0, 0.0, 0.5))
        images.append(render(scene, "RAYTRACE", f"ior-{ior:g}", tmp_path)["Combined"])
        final.release_caches()
    # Equal up to the last bits of Embree's parallel BVH builds (they differ from run to run).
    np.testing.assert_allclose(images[1], images[0], rtol=1e-3, atol=1e-4)


# -- lights -------------------------------------------------------------------------------------------

def lights_scene(lights):
    """A floor, a candidate box with all effects, and ``lights(scene)`` adding the lights."""
    scene = small_scene()
    showcase.mesh_object("Floor", showcase.plane(10.0), showcase.principled("Floor", (0.6, 0.6, 0.6)))
    box = showcase.mesh_object("Box", showcase.cube(0.8), showcase.principled("Box", (0.3, 0.5, 0.7)),
                               location=(0.0, 0.0, 0.4))
    showcase.tag(box, shadows=True, reflections=True, refractions=True)
    lights(scene)
    showcase.add_camera((2.0, -4.0, 2.5), (0.0, 0.0, 0.3))
    return scene


def render_modes(scene, name, tmp_path, modes=("RASTER", "RAYTRACE")):
    return {mode: render(scene, mode, name, tmp_path)["Combined"][..., :3] for mode in modes}


def test_no_lights_and_zero_strength_lights_give_the_same_frame(tmp_path):
    none = render_modes(lights_scene(lambda scene: None), "no-lights", tmp_path)
    assert session.last_frame().stats["shadow_rays"] == 0
    final.release_caches()

    def zero(scene):
        showcase.add_light("POINT", (1.0, -1.0, 2.0), 0.0, name="Zero")
        showcase.add_light("SUN", (0, 0, 5), 0.0, rotation=(0.5, 0.0, 0.0), name="ZeroSun")

    zeros = render_modes(lights_scene(zero), "zero-lights", tmp_path)
    for mode in none:
        assert none[mode].max() > 0  # the world's ambient light
        np.testing.assert_allclose(zeros[mode], none[mode], atol=1e-6)


def test_64_lights_add_up_to_one_of_64_times_the_power(tmp_path):
    def one(scene):
        showcase.add_light("POINT", (1.5, -1.5, 2.5), 640.0, name="One")

    def many(scene):
        for index in range(64):
            showcase.add_light("POINT", (1.5, -1.5, 2.5), 10.0, name=f"Lamp{index:02d}")

    scene = lights_scene(one)
    scene.phrt.shadow_map_size = 128
    single = render_modes(scene, "one-light", tmp_path)
    final.release_caches()
    scene = lights_scene(many)
    scene.phrt.shadow_map_size = 128
    sixty_four = render_modes(scene, "64-lights", tmp_path)
    for mode in single:
        assert single[mode].max() > 0.2
        np.testing.assert_allclose(sixty_four[mode], single[mode], rtol=1e-3, atol=1e-4)


def test_a_light_inside_a_closed_box_lights_nothing_outside(tmp_path):
    def boxed(scene):
        showcase.add_light("POINT", (0.0, 0.0, 0.4), 1000.0, name="Inside")
        showcase.add_light("SUN", (0, 0, 5), 1.0, rotation=(0.5, 0.0, 0.3), name="Sun")

    def sun_only(scene):
        showcase.add_light("SUN", (0, 0, 5), 1.0, rotation=(0.5, 0.0, 0.3), name="Sun")

    inside = render_modes(lights_scene(boxed), "light-in-box", tmp_path)
    final.release_caches()
    outside = render_modes(lights_scene(sun_only), "light-outside", tmp_path)
    for mode in inside:
        difference = np.abs(inside[mode] - outside[mode]).max(axis=-1)
        assert np.mean(difference < 1e-3) > 0.995, (mode, difference.max())


def test_a_light_of_1e9_watts_stays_finite(tmp_path):
    def blinding(scene):
        showcase.add_light("POINT", (1.0, -1.0, 2.0), 1e9, name="Blinding")
        showcase.add_light("SUN", (0, 0, 5), 1e9, rotation=(0.5, 0.0, 0.3), name="BlindingSun")

    images = render_modes(lights_scene(blinding), "1e9", tmp_path, modes=MODES)
    for image in images.values():
        assert image.max() > 1e3 and image.max() <= 1e6


# -- the budget through a replay ---------------------------------------------------------------------

def test_budgets_of_zero_huge_and_changing_every_frame_in_a_replay(tmp_path):
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    scene.phrt.shadow_map_size = 256
    budgets = [0.0, 1e9, 0.0, 1e9, 50.0, 3.0]
    for frame, budget in enumerate(budgets, start=1):
        scene.phrt.budget_ms = budget
        scene.phrt.keyframe_insert("budget_ms", frame=frame)
    for curve in scene.animation_data.action.fcurves if hasattr(scene.animation_data.action, "fcurves") else []:
        for point in curve.keyframe_points:
            point.interpolation = "CONSTANT"
    result = replay.replay(scene, scene.camera, (1, len(budgets)), "HYBRID", tmp_path / "run", images="none")
    assert result.frames_done == len(budgets) and not result.cancelled
    frames = run_files.read_frames(tmp_path / "run")
    assert [row["budget_ms"] for row in frames] == pytest.approx(budgets)
    selection = run_files.read_selection(tmp_path / "run")
    for row, budget in zip(frames, budgets):
        reasons = [entry["reason"] for entry in selection if entry["frame"] == row["frame"]]
        if budget == 0.0:
            assert row["n_selected"] == 0 and row["predicted_trace_ms"] == 0
        if budget == 1e9:
            assert row["n_selected"] > 0 and "over_budget" not in reasons
    summary = run_files.read_summary(tmp_path / "run")
    assert summary["non_finite_values_dropped"] == 0 and summary["partial"] is False
