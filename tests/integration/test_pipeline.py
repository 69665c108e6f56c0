"""Whole-frame renders through bpy (``bpy.ops.render.render``) checked against
analytic geometry: a mirror sphere's reflection of a red cube, refraction of a
checkerboard through a glass slab, a fence's ray traced shadow against its
exact projection and against the shadow map, shadows against Cycles, an
element touching the camera, and no NaN/Inf in any pass of any frame.

Frames are small (160x120 to 320x240).  Set ``PHRT_TEST_IMAGES=<dir>`` to keep
a PNG of every rendered frame for a look."""
import os
import tempfile
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")

from phrt import compat  # noqa: E402
from phrt.engine import extract, final, session  # noqa: E402
from phrt.phrt_addon.report import metrics  # noqa: E402
from phrt.phrt_addon.scene import shading  # noqa: E402
from phrt.sample_scenes import showcase  # noqa: E402
from phrt_render import box_hit, erode, plane_hit  # noqa: E402

MODES = ("RASTER", "HYBRID", "RAYTRACE")


# Registered once (conftest's ``blender``); every test starts with nothing cached.
pytestmark = pytest.mark.usefixtures("fresh_caches")


# -- rendering and reading back ------------------------------------------------------------------

def read_passes(path):
    """Every pass of a multilayer EXR: {'Combined': (h,w,4), 'Depth': (h,w,1), ...}, top row first.
    Blender 5.x writes one part per pass, 4.5 one part with every pass: channels are
    named 'ViewLayer.<pass>.<component>' in both."""
    import OpenEXR

    by_pass = {}
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        for part in exr.parts:
            for channel_name, channel in part.channels.items():
                pass_name, component = channel_name.split(".", 1)[1].rsplit(".", 1)
                by_pass.setdefault(pass_name, []).append((component, np.asarray(channel.pixels, np.float32)))
    order = {"R": 0, "G": 1, "B": 2, "A": 3, "X": 0, "Y": 1, "Z": 2}
    return {name: np.stack([pixels for _, pixels in sorted(channels, key=lambda item: order.get(item[0], 9))],
                           axis=-1)
            for name, channels in by_pass.items()}


def render(scene, mode, name, tmp_path, engine="PHRT"):
    """Render one frame to a multilayer EXR and return its passes; asserts every value is finite."""
    scene.render.engine = engine
    if engine == "PHRT":
        scene.phrt.mode = mode
    settings = scene.render.image_settings
    compat.set_image_format(settings, compat.MULTILAYER_EXR)
    settings.color_depth = "32"
    path = Path(tmp_path) / f"{name}-{mode}.exr"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    passes = read_passes(path)
    assert "Combined" in passes
    for pass_name, pixels in passes.items():
        bad = ~np.isfinite(pixels)
        assert not np.any(bad), f"{name} {mode}: {bad.sum()} NaN/Inf values in pass {pass_name}"
    keep = os.environ.get("PHRT_TEST_IMAGES")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        metrics.write_image(Path(keep) / f"{name}-{mode}.png", passes["Combined"][..., :3])
    return passes


def camera_rays(scene):
    """Origins and unit directions through every pixel centre, (h, w, 3), top row first - the
    camera PHRT itself renders with."""
    snapshot = extract.extract(bpy.context.evaluated_depsgraph_get())
    origins, directions = snapshot.camera.pixel_rays()
    return origins[::-1], directions[::-1]


def selected_elements():
    return {row["element"] for row in session.last_frame().rows if row["selected"]}


# -- analytic geometry (numpy, whole images) ------------------------------------------------------------

def sphere_hit(origins, directions, centre, radius):
    """Distance to the first hit of a sphere along unit rays (inf on a miss)."""
    relative = origins - np.asarray(centre, float)
    b = np.sum(relative * directions, axis=-1)
    c = np.sum(relative * relative, axis=-1) - radius ** 2
    disc = b * b - c
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc > 0) & (t > 0), t, np.inf)


def red_dominant(rgb):
    return (rgb[..., 0] > 0.05) & (rgb[..., 0] > 3.0 * np.maximum(rgb[..., 1], rgb[..., 2]))


# -- 1. mirror sphere in front of a red cube ---------------------------------------------------------

SPHERE_CENTRE = np.array([0.0, 0.0, 1.0])
SPHERE_RADIUS = 1.0
CUBE_LOW = np.array([1.0, -2.8, 0.2])
CUBE_HIGH = np.array([2.6, -1.2, 1.8])


def mirror_scene():
    scene = showcase.empty_scene(200, 150)
    showcase.mesh_object("Floor", showcase.plane(20.0), showcase.principled("Floor", (0.5, 0.5, 0.5), roughness=0.9))
    red = showcase.principled("Red", (0.8, 0.02, 0.02), roughness=0.6, emission=((1.0, 0.0, 0.0), 1.0))
    showcase.mesh_object("RedCube", showcase.cube(1.0), red, location=tuple((CUBE_LOW + CUBE_HIGH) / 2),
                         scale=tuple(CUBE_HIGH - CUBE_LOW))
    mirror = showcase.principled("Mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
    sphere = showcase.mesh_object("MirrorSphere", showcase.sphere(SPHERE_RADIUS, 96, 48), mirror,
                                  location=tuple(SPHERE_CENTRE), smooth=True)
    showcase.tag(sphere, shadows=False, reflections=True, refractions=False)
    showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(np.radians(40), 0.0, np.radians(-30)), name="Sun")
    showcase.add_camera((0.0, -6.0, 1.5), tuple(SPHERE_CENTRE), lens=35.0)
    return scene


def expected_red_reflection(scene):
    """Per pixel: 'sure red' (the mirror ray hits the cube well inside), 'sure not red' (it misses
    the cube by a margin or hits the floor first), on sphere pixels away from the silhouette."""
    origins, directions = camera_rays(scene)
    t = sphere_hit(origins, directions, SPHERE_CENTRE, SPHERE_RADIUS)
    inner = np.isfinite(sphere_hit(origins, directions, SPHERE_CENTRE, 0.97 * SPHERE_RADIUS))
    points = origins + directions * np.where(np.isfinite(t), t, 0.0)[..., None]
    normals = shading.normalize(points - SPHERE_CENTRE)
    reflected = directions - 2.0 * np.sum(directions * normals, axis=-1)[..., None] * normals
    start = points + normals * 1e-6
    margin = 0.1
    floor_t = plane_hit(start, reflected, 0.0)
    hits_small = box_hit(start, reflected, CUBE_LOW + margin, CUBE_HIGH - margin)
    hits_large = box_hit(start, reflected, CUBE_LOW - margin, CUBE_HIGH + margin)
    sure_red = inner & np.isfinite(hits_small) & (hits_small < floor_t)
    sure_not_red = inner & ~(np.isfinite(hits_large) & (hits_large < floor_t + margin))
    return sure_red, sure_not_red


def test_mirror_sphere_reflects_the_red_cube_where_the_mirror_rays_say(tmp_path):
    scene = mirror_scene()
    sure_red, sure_not_red = expected_red_reflection(scene)
    assert sure_red.sum() > 150 and sure_not_red.sum() > 1500
    results = {}
    for mode in ("RAYTRACE", "RASTER"):
        red = red_dominant(render(scene, mode, "mirror", tmp_path)["Combined"][..., :3])
        results[mode] = (red[sure_red].mean(), red[sure_not_red].mean())
    assert session.last_frame().stats["n_selected"] == 0
    assert results["RAYTRACE"][0] > 0.97, results
    assert results["RAYTRACE"][1] < 0.01, results
    assert results["RASTER"][0] < 0.01, results  # raster reflects the world colour only


def test_hybrid_traces_the_mirror_sphere_given_the_budget(tmp_path):
    scene = mirror_scene()
    scene.phrt.budget_ms = 10000.0
    sure_red, sure_not_red = expected_red_reflection(scene)
    for frame in range(2):  # the second frame runs with a warm cost model
        passes = render(scene, "HYBRID", f"mirror-{frame}", tmp_path)
    assert "MirrorSphere" in selected_elements()
    red = red_dominant(passes["Combined"][..., :3])
    assert red[sure_red].mean() > 0.97
    assert red[sure_not_red].mean() < 0.01
    # The Selected pass marks the sphere's pixels.
    assert passes["PHRT Selected"][..., 0][sure_red | sure_not_red].min() == 1.0


# -- 2. glass slab over a checkerboard -----------------------------------------------------------------

SLAB_LOW = np.array([-1.0, -1.0, 0.3])
SLAB_HIGH = np.array([1.0, 1.0, 0.6])
SLAB_IOR = 1.5
CHECKER_CELL = 0.25


def checker_floor(size=8.0):
    """A grid of CHECKER_CELL squares, two materials by parity (face material index)."""
    import bmesh

    segments = int(round(size / CHECKER_CELL))

    def build(bm):
        bmesh.ops.create_grid(bm, x_segments=segments, y_segments=segments, size=size / 2.0)
        for face in bm.faces:
            centre = face.calc_center_median()
            face.material_index = checker_parity(np.array([centre.x, centre.y]))

    floor = showcase.mesh_object("Checker", build, showcase.principled("Light", (0.8, 0.8, 0.8), roughness=1.0))
    floor.data.materials.append(showcase.principled("Dark", (0.05, 0.05, 0.05), roughness=1.0))
    return floor


def checker_parity(xy):
    cells = np.floor(np.asarray(xy) / CHECKER_CELL).astype(np.int64)
    return (cells[..., 0] + cells[..., 1]) % 2  # 0: light, 1: dark


def near_checker_edge(xy, margin):
    fraction = np.mod(np.asarray(xy) / CHECKER_CELL, 1.0)
    distance = np.minimum(fraction, 1.0 - fraction) * CHECKER_CELL
    return np.any(distance < margin, axis=-1)


def slab_scene():
    scene = showcase.empty_scene(240, 180)
    checker_floor()
    glass = showcase.principled("Glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=SLAB_IOR)
    slab = showcase.mesh_object("GlassSlab", showcase.cube(1.0), glass, location=tuple((SLAB_LOW + SLAB_HIGH) / 2),
                                scale=tuple(SLAB_HIGH - SLAB_LOW))
    showcase.tag(slab, shadows=False, reflections=True, refractions=True)
    showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(0.0, 0.0, 0.0), name="Sun")
    showcase.add_camera((0.0, -3.2, 3.4), (0.0, 0.0, 0.4), lens=40.0)
    return scene


def slab_expectations(scene):
    """Floor parity seen through the slab's top face: bent by Snell's law (refracted) and
    straight (raster), on pixels whose refracted path stays inside the slab and lands away
    from checker edges by ~2 pixels' worth of floor."""
    origins, directions = camera_rays(scene)
    t_top = plane_hit(origins, directions, SLAB_HIGH[2])
    top = origins + directions * np.where(np.isfinite(t_top), t_top, 0.0)[..., None]
    margin = 0.05
    on_top = np.isfinite(t_top) & np.all((top[..., :2] > SLAB_LOW[:2] + margin) &
                                         (top[..., :2] < SLAB_HIGH[:2] - margin), axis=-1)
    flat = directions.reshape(-1, 3)
    normal = np.tile([0.0, 0.0, 1.0], (len(flat), 1))
    inside, _ = shading.refract(flat, normal, np.full(len(flat), 1.0 / SLAB_IOR))
    inside = inside.reshape(directions.shape)
    t_bottom = (SLAB_LOW[2] - SLAB_HIGH[2]) / inside[..., 2]
    bottom = top + inside * t_bottom[..., None]
    stays_inside = np.all((bottom[..., :2] > SLAB_LOW[:2] + margin) & (bottom[..., :2] < SLAB_HIGH[:2] - margin),
                          axis=-1)
    # Leaves parallel to the incoming ray (parallel faces).
    bent = bottom + directions * (-SLAB_LOW[2] / directions[..., 2])[..., None]
    straight = origins + directions * plane_hit(origins, directions, 0.0)[..., None]
    # ~2 pixels of floor: the pixel footprint at the floor is about distance * pixel angle.
    pixel_angle = np.linalg.norm(directions[0, 1] - directions[0, 0])
    footprint = 2.0 * np.linalg.norm(bent - origins, axis=-1) * pixel_angle / np.abs(directions[..., 2])
    valid = on_top & stays_inside & ~near_checker_edge(bent[..., :2], footprint[..., None]) \
        & ~near_checker_edge(straight[..., :2], footprint[..., None])
    return valid, checker_parity(bent[..., :2]), checker_parity(straight[..., :2])


def dark_cells(image, valid):
    luminance = image[..., :3].mean(axis=-1)
    threshold = 0.5 * (np.percentile(luminance[valid], 90) + np.percentile(luminance[valid], 10))
    return luminance < threshold


def test_checker_seen_through_a_glass_slab_is_shifted_by_snell_law(tmp_path):
    scene = slab_scene()
    valid, bent_parity, straight_parity = slab_expectations(scene)
    assert valid.sum() > 1000
    differs = (bent_parity != straight_parity) & valid
    # Bending changes the cell seen on some pixels and not on others: neither the unbent nor an
    # inverted checker can pass.
    assert 0.15 * valid.sum() < differs.sum() < 0.85 * valid.sum()
    traced = render(scene, "RAYTRACE", "slab", tmp_path)
    raster = render(scene, "RASTER", "slab", tmp_path)
    traced_dark = dark_cells(traced["Combined"], valid)
    raster_dark = dark_cells(raster["Combined"], valid)
    traced_match = np.mean(traced_dark[valid] == (bent_parity[valid] == 1))
    raster_match = np.mean(raster_dark[valid] == (straight_parity[valid] == 1))
    assert traced_match > 0.97, f"refracted checker matches Snell's law on {traced_match:.1%} of the pixels"
    # Raster draws glass as a straight-through blend: the unbent checker.
    assert raster_match > 0.97, f"raster checker matches the straight view on {raster_match:.1%}"
    assert np.mean(traced_dark[differs] == (bent_parity[differs] == 1)) > 0.95


# -- 3. a fence's ray traced shadow: exact outline, crisper than the shadow map ------------------------

POST_SIZE = (0.05, 0.05, 1.0)
POST_XS = np.linspace(-0.6, 0.6, 5)
SUN_ROTATION = (np.radians(35.0), 0.0, np.radians(15.0))


def fence_boxes():
    boxes = [(np.array([x - POST_SIZE[0] / 2, -POST_SIZE[1] / 2, 0.0]),
              np.array([x + POST_SIZE[0] / 2, POST_SIZE[1] / 2, POST_SIZE[2]])) for x in POST_XS]
    rail = (np.array([-0.7, -0.015, 0.6]), np.array([0.7, 0.015, 0.66]))
    return boxes + [rail]


def fence_scene():
    import bmesh

    scene = showcase.empty_scene(240, 180)
    scene.world.color = (0.0, 0.0, 0.0)
    showcase.mesh_object("Floor", showcase.plane(40.0), showcase.principled("Floor", (0.6, 0.6, 0.6), roughness=1.0))

    def build(bm):
        for low, high in fence_boxes():
            result = bmesh.ops.create_cube(bm, size=1.0)
            bmesh.ops.scale(bm, vec=tuple(high - low), verts=result["verts"])
            bmesh.ops.translate(bm, vec=tuple((low + high) / 2), verts=result["verts"])

    fence = showcase.mesh_object("Fence", build, showcase.principled("Wood", (0.45, 0.3, 0.15), roughness=0.7))
    showcase.tag(fence, shadows=True, reflections=False, refractions=False)
    sun = showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=SUN_ROTATION, name="Sun")
    sun.data.angle = 0.0
    # A third of a pixel off the posts' grid, so that no pixel centre lies exactly on a post's face.
    camera = showcase.add_camera((0.0033, 0.6, 6.0), (0.0033, 0.6, 0.0))
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = 2.4
    return scene


def fence_expectations(scene):
    """Floor pixels (not covered by the fence from the camera), their analytic shadow, and
    whether they are 'sure' (the shadow does not change within a pixel around them)."""
    origins, directions = camera_rays(scene)
    sun = bpy.data.objects["Sun"]
    to_sun = shading.normalize(np.array(sun.matrix_world, float)[:3, 2])  # the lamp shines down its -Z
    floor_points = origins + directions * plane_hit(origins, directions, 0.0)[..., None]
    covered_by_fence = np.zeros(floor_points.shape[:2], bool)
    for low, high in fence_boxes():
        covered_by_fence |= np.isfinite(box_hit(origins, directions, low - 0.005, high + 0.005))

    def shadowed(points):
        result = np.zeros(points.shape[:2], bool)
        for low, high in fence_boxes():
            result |= np.isfinite(box_hit(points + to_sun * 1e-6, np.broadcast_to(to_sun, points.shape), low, high))
        return result

    shadow = shadowed(floor_points)
    pixel = np.linalg.norm(floor_points[0, 1] - floor_points[0, 0])
    sure = np.ones_like(shadow)
    for offset in ([1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]):
        sure &= shadowed(floor_points + pixel * np.array(offset, float)) == shadow
    return ~covered_by_fence, shadow, sure


def lit_fraction(image, floor):
    luminance = image[..., :3].mean(axis=-1)
    return luminance / np.percentile(luminance[floor], 99)


def test_fence_shadow_is_exact_and_crisper_than_the_shadow_map(tmp_path):
    scene = fence_scene()
    floor, shadow, sure = fence_expectations(scene)
    assert (shadow & floor & sure).sum() > 500 and (~shadow & floor & sure).sum() > 5000
    edge = floor & ~sure
    fractions = {}
    for mode in ("RAYTRACE", "RASTER"):
        lit = lit_fraction(render(scene, mode, "fence", tmp_path)["Combined"], floor)
        classified_lit = lit > 0.5
        agree = np.mean(classified_lit[floor & sure] == ~shadow[floor & sure])
        partial = np.mean((lit[edge] > 0.1) & (lit[edge] < 0.9))
        fractions[mode] = (agree, partial)
    traced_agree, traced_partial = fractions["RAYTRACE"]
    raster_agree, raster_partial = fractions["RASTER"]
    assert traced_agree > 0.995, fractions
    # One shadow ray per pixel: an edge pixel is lit or not; the shadow map's PCF and texels blur it.
    assert traced_partial < 0.05, fractions
    assert raster_partial > 3 * traced_partial + 0.1, fractions
    assert raster_agree < traced_agree, fractions


# -- 4. shadows agree with Cycles ----------------------------------------------------------------------

def cycles_scene():
    scene = showcase.empty_scene(160, 120)
    scene.world.color = (0.0, 0.0, 0.0)
    showcase.mesh_object("Floor", showcase.plane(12.0), showcase.principled("Floor", (0.7, 0.7, 0.7), roughness=1.0))
    cube = showcase.mesh_object("Cube", showcase.cube(1.0), showcase.principled("Blue", (0.1, 0.2, 0.7), roughness=0.8),
                                location=(-0.8, 0.3, 0.5), rotation=(0.0, 0.0, np.radians(25)))
    ball = showcase.mesh_object("Ball", showcase.sphere(0.6, 48, 24),
                                showcase.principled("Green", (0.2, 0.6, 0.2), roughness=0.8),
                                location=(0.9, -0.2, 0.6), smooth=True)
    post = showcase.mesh_object("Post", showcase.cube(1.0), showcase.principled("Grey", (0.5, 0.5, 0.5)),
                                location=(0.0, 1.5, 0.75), scale=(0.08, 0.08, 1.5))
    for obj in (cube, ball, post):
        showcase.tag(obj, shadows=True, reflections=False, refractions=False)
    sun = showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(np.radians(65), 0.0, np.radians(-40)), name="Sun")
    sun.data.angle = 0.0
    showcase.add_camera((3.0, -4.0, 3.5), (-0.3, 0.6, 0.3), lens=35.0)
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.samples = 8
    cycles.max_bounces = 0
    cycles.use_denoising = False
    cycles.use_adaptive_sampling = False
    cycles.seed = 1
    return scene


def test_raytraced_shadows_agree_with_cycles(tmp_path):
    scene = cycles_scene()
    phrt_passes = render(scene, "RAYTRACE", "cycles", tmp_path)
    assert selected_elements() == {"Cube", "Ball", "Post"}
    cycles_image = render(scene, "CYCLES", "cycles", tmp_path, engine="CYCLES")["Combined"]
    # Floor: covered pixels of the one non-candidate element (everything else is tagged).
    floor = (phrt_passes["PHRT Candidate"][..., 0] == 0) & (phrt_passes["Depth"][..., 0] < 1e9)
    # Away from the floor's own outline and the casters' silhouettes (anti-aliased in Cycles).
    floor = erode(floor)
    assert floor.sum() > 0.3 * floor.size
    lit_phrt = lit_fraction(phrt_passes["Combined"], floor) > 0.5
    lit_cycles = lit_fraction(cycles_image, floor) > 0.5
    shadowed = np.mean(~lit_cycles[floor])
    assert shadowed > 0.07  # there are shadows to compare
    agreement = np.mean(lit_phrt[floor] == lit_cycles[floor])
    overlap = np.sum(~lit_phrt & ~lit_cycles & floor) / np.sum((~lit_phrt | ~lit_cycles) & floor)
    assert agreement > 0.97, f"lit/unlit agree on {agreement:.1%} of the floor (shadowed {shadowed:.1%})"
    assert overlap > 0.85, f"shadows overlap (intersection over union) {overlap:.1%}"


# -- 5. extreme cases: an element touching the camera, every mode ------------------------------------

def test_elements_touching_the_camera_render_finite_frames(tmp_path):
    scene = showcase.empty_scene(160, 120)
    showcase.mesh_object("Floor", showcase.plane(10.0), showcase.principled("Floor", (0.6, 0.6, 0.6)))
    glass = showcase.principled("Glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.5)
    mirror = showcase.principled("Mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0)
    camera_location = (0.0, -3.0, 1.0)
    # A glass box around the camera, a mirror plane through its near clip plane, a post at 1 mm.
    around = showcase.mesh_object("AroundCamera", showcase.cube(0.3), glass, location=camera_location)
    through = showcase.mesh_object("ThroughNearPlane", showcase.plane(0.6), mirror,
                                   location=(0.0, -3.0 + 0.05, 1.0), rotation=(np.radians(80), 0.0, 0.0))
    touching = showcase.mesh_object("Touching", showcase.cube(0.2), mirror, location=(0.1, -3.0 + 0.101, 1.0))
    for obj in (around, through, touching):
        showcase.tag(obj, shadows=True, reflections=True, refractions=True)
    showcase.add_light("POINT", camera_location, 100.0, name="HeadLamp")  # a light at the eye, too
    showcase.add_light("SUN", (0, 0, 5), 2.0, rotation=(np.radians(30), 0.0, 0.0), name="Sun")
    showcase.add_camera(camera_location, (0.0, 0.0, 0.5))
    for mode in MODES:
        passes = render(scene, mode, "touching", tmp_path)
        assert session.last_frame().stats["mode"] == mode
        assert passes["Combined"][..., :3].max() > 0


def move_and_scale_world(scene, scale, offset):
    """Scale the whole scene about the origin by ``scale`` and move it by ``offset`` (x, y, z),
    clip range included: the same picture at other coordinates."""
    offset = np.asarray(offset, float)
    for obj in scene.objects:
        obj.location = tuple(np.array(obj.location) * scale + offset)
        if obj.type == "CAMERA":
            obj.data.clip_start *= scale
            obj.data.clip_end *= scale
            obj.data.ortho_scale *= scale
        elif obj.type != "LIGHT":
            obj.scale = tuple(np.array(obj.scale) * scale)
    bpy.context.view_layer.update()


@pytest.mark.parametrize("scale,offset", [(1e-3, 0.0), (1.0, 1e5), (1e3, 0.0), (1e-2, 1e3)])
def test_traced_shadows_do_not_depend_on_scale_or_position(scale, offset, tmp_path):
    """The Cycles comparison scene at 1e-3..1e5 world units: same lit/unlit floor, no acne."""
    scene = cycles_scene()
    reference = render(scene, "RAYTRACE", "scale-reference", tmp_path)
    floor = erode((reference["PHRT Candidate"][..., 0] == 0) & (reference["Depth"][..., 0] < 1e9))
    lit_reference = lit_fraction(reference["Combined"], floor) > 0.5
    final.release_caches()
    move_and_scale_world(scene, scale, (offset, offset, offset))
    moved = render(scene, "RAYTRACE", f"scale-{scale:g}-{offset:g}", tmp_path)
    moved_floor = erode((moved["PHRT Candidate"][..., 0] == 0) & (moved["Depth"][..., 0] < 1e9))
    assert np.mean(moved_floor == floor) > 0.99
    both = floor & moved_floor
    lit_moved = lit_fraction(moved["Combined"], both) > 0.5
    agreement = np.mean(lit_moved[both] == lit_reference[both])
    assert agreement > 0.995, f"lit/unlit floor agree on {agreement:.2%} at scale {scale}, offset {offset}"
    acne = np.mean(~lit_moved[both] & lit_reference[both])
    assert acne < 0.002


SCENES = {"mirror": mirror_scene, "slab": slab_scene, "fence": fence_scene, "cycles": cycles_scene,
          "showcase": lambda: showcase.build_showcase(240, 180)}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_every_pass_is_finite_in_every_mode(name, tmp_path):
    scene = SCENES[name]()
    for mode in MODES:
        render(scene, mode, f"finite-{name}", tmp_path)  # render() asserts every value of every pass is finite
        assert session.last_frame().stats["mode"] == mode


def test_a_new_file_far_away_renders_like_the_first(tmp_path):
    """The standalone renderer is kept per scene name: a new file whose scene is also called
    'Scene' but lies at 1e5 must not inherit the first one's trace origin (acne, lost shadows)."""
    first = render(cycles_scene(), "RAYTRACE", "new-file-first", tmp_path)
    floor = erode((first["PHRT Candidate"][..., 0] == 0) & (first["Depth"][..., 0] < 1e9))
    scene = cycles_scene()  # read_homefile: a new file, same scene and object names, caches kept
    move_and_scale_world(scene, 1.0, (1e5, 1e5, 1e5))
    second = render(scene, "RAYTRACE", "new-file-far", tmp_path)
    lit_first = lit_fraction(first["Combined"], floor) > 0.5
    lit_second = lit_fraction(second["Combined"], floor) > 0.5
    assert np.mean(lit_first[floor] == lit_second[floor]) > 0.995


@pytest.mark.parametrize("factor", [10, 100])
def test_telephoto_view_of_a_small_scene_has_no_shadow_acne(factor, tmp_path):
    """The Cycles comparison scene seen from ``factor`` times farther with a ``factor`` times longer
    lens (about the same framing): G-buffer positions carry float32 error of the camera distance.
    Traced shadows must not darken pixels the shadow map lights, away from the raster's edges."""
    scene = cycles_scene()
    camera = scene.camera
    target = np.array([-0.3, 0.6, 0.3])
    camera.location = tuple(target + (np.array(camera.location) - target) * factor)
    camera.data.lens *= factor
    camera.data.clip_start *= factor
    camera.data.clip_end *= factor
    traced = render(scene, "RAYTRACE", f"telephoto-{factor}", tmp_path)["Combined"][..., :3].mean(axis=-1)
    raster = render(scene, "RASTER", f"telephoto-{factor}", tmp_path)["Combined"][..., :3].mean(axis=-1)
    padded = np.pad(raster, 2, mode="edge")
    smooth = np.ones_like(raster, bool)  # no raster edge (shadow or silhouette) within 2 pixels
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            neighbour = padded[2 + dy:2 + dy + raster.shape[0], 2 + dx:2 + dx + raster.shape[1]]
            smooth &= np.abs(neighbour - raster) <= 0.2 * raster + 1e-3
    assert smooth.sum() > 0.5 * smooth.size
    acne = smooth & (traced < 0.6 * raster)
    assert acne.sum() == 0, f"{acne.sum()} acne pixels at {factor}x camera distance"
