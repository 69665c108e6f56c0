"""One rule per physical question, rastered and traced alike (phrt_addon/scene/rules.py), rendered
through Blender with the real engine, GPU raster and Embree.

The window trick: a clear pane of IOR 1 (or below: clamped to 1) bends and reflects nothing, so
a RAYTRACE frame in which the pane is traced (everything behind it shaded by the tracer's
hits) must equal the RASTER frame of the same scene without the pane (everything shaded from
the GPU's G-buffer).  Behind the pane: a textured wall magnified (bilinear, wrapping
sampling), a texture wider than 2048 texels (the prepared, averaged image), an object without
UVs (coordinates read 0), one with NaN UVs, an alpha card (blended, passed through) and a 30%
transmissive curtain (IOR 1, rough: raster transparency does not bend or mirror, and there the
physics agrees with it).  Any difference between the two paths in one of those rules shows up
as pixels that disagree.

What casts a shadow is checked against the analytic shadows of a sun, in the shadow maps and
for shadow rays; K = 0 against the Candidate pass; max_bounces 0, 1 and 32 against what
they mean."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

import bmesh  # noqa: E402

from phrt.engine import final, session  # noqa: E402
from phrt.phrt_addon.scene import rules  # noqa: E402
from phrt.sample_scenes import showcase  # noqa: E402
from phrt_render import box_hit, camera_rays, erode, plane_hit, render, selected_elements, set_world  # noqa: E402

WIDTH, HEIGHT = 128, 96


@pytest.fixture(autouse=True)
def fresh(blender):
    final.release_caches()
    yield
    final.release_caches()


def image_texture(name, width, height, seed):
    image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
    pixels = np.random.default_rng(seed).uniform(0.05, 0.95, (height, width, 4)).astype(np.float32)
    pixels[..., 3] = 1.0
    image.pixels.foreach_set(pixels.ravel())
    return image


def textured(name, image, roughness=0.9):
    material = showcase.principled(name, (1.0, 1.0, 1.0), roughness=roughness)
    nodes, links = material.node_tree.nodes, material.node_tree.links
    node = nodes.new("ShaderNodeTexImage")
    node.image = image
    links.new(node.outputs["Color"], nodes.get("Principled BSDF").inputs["Base Color"])
    return material


def grid(size_x, size_y, uvs=True):
    def build(bm):
        if uvs:
            bm.loops.layers.uv.new("UVMap")
        bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=0.5, calc_uvs=uvs)
        bmesh.ops.scale(bm, vec=(size_x, size_y, 1.0), verts=bm.verts)
    return build


def window_scene(window_ior=None):
    """Walls and props behind the place of a window pane (y = -1.2), lights without shadows."""
    scene = showcase.empty_scene(WIDTH, HEIGHT)
    scene.phrt.shadow_map_size = 256
    set_world(scene, (0.05, 0.06, 0.08))
    # A magnified 8 x 6 texture (bilinear between texels) and a 2100 x 4 one (prepared: averaged).
    showcase.mesh_object("SmallTexture", grid(2.2, 2.0), textured("Small", image_texture("small", 8, 6, 1)),
                         location=(-1.1, 1.0, 1.0), rotation=(np.radians(90), 0.0, 0.0))
    showcase.mesh_object("WideTexture", grid(2.2, 2.0), textured("Wide", image_texture("wide", 2100, 4, 2)),
                         location=(1.1, 1.0, 1.0), rotation=(np.radians(90), 0.0, 0.0))
    no_uv = showcase.mesh_object("NoUV", showcase.cube(0.4), textured("NoUVTex", image_texture("nouv", 4, 4, 3)),
                                 location=(-0.9, 0.2, 0.5), rotation=(0.3, 0.2, 0.4))
    assert len(no_uv.data.uv_layers) == 0
    nan_uv = showcase.mesh_object("NanUV", grid(0.5, 0.5), textured("NanTex", image_texture("nan", 4, 4, 4)),
                                  location=(0.9, 0.3, 1.45), rotation=(np.radians(80), 0.0, 0.2))
    uv = np.full(len(nan_uv.data.loops) * 2, np.nan, np.float32)
    uv[::3] = 0.3
    nan_uv.data.uv_layers.active.data.foreach_set("uv", uv)
    showcase.mesh_object("Card", grid(0.6, 0.8), showcase.principled("CardRed", (0.9, 0.1, 0.05), alpha=0.4),
                         location=(0.0, 0.0, 0.9), rotation=(np.radians(90), 0.0, 0.0))
    showcase.mesh_object("Curtain", grid(0.5, 0.6),
                         showcase.principled("Curtain", (0.2, 0.5, 0.9), transmission=0.3, roughness=0.6, ior=1.0),
                         location=(0.6, -0.2, 0.6), rotation=(np.radians(90), 0.0, -0.3))
    showcase.mesh_object("Floor", showcase.plane(8.0), showcase.principled("Floor", (0.5, 0.45, 0.4), roughness=1.0))
    showcase.add_light("SUN", (0, 0, 5), 2.0, rotation=(np.radians(50), 0.0, np.radians(20)), name="Sun",
                       use_shadow=False)
    showcase.add_light("POINT", (-1.5, -2.0, 2.5), 150.0, name="Lamp", use_shadow=False)
    showcase.add_camera((0.1, -4.5, 1.3), (0.0, 0.5, 0.9), lens=30.0)
    if window_ior is not None:
        pane = showcase.mesh_object("Window", grid(2.6, 1.6), showcase.principled(
            "Pane", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=window_ior),
            location=(0.0, -1.2, 1.0), rotation=(np.radians(90), 0.0, 0.0))
        showcase.tag(pane, shadows=False, reflections=True, refractions=True)
    return scene


@pytest.mark.parametrize("ior", [1.0, 0.6])
def test_behind_a_clear_pane_the_tracer_shades_like_the_raster(ior, tmp_path):
    """Texture sampling, no-UV and NaN-UV coordinates, alpha and transmission: the traced view
    through an IOR-1 pane equals the raster view without it."""
    raster = render(window_scene(None), "RASTER", f"window-none-{ior}", tmp_path)["Combined"][..., :3]
    traced_passes = render(window_scene(ior), "RAYTRACE", f"window-{ior}", tmp_path)
    assert selected_elements() == {"Window"}
    traced = traced_passes["Combined"][..., :3]
    pane = traced_passes["PHRT Selected"] > 0.5
    assert pane.sum() > 0.3 * pane.size
    # Away from object outlines (a pixel at an edge may be covered by one path and not the other).
    depth = traced_passes["Depth"]
    smooth = np.ones_like(pane)
    for axis in (0, 1):
        jump = np.abs(np.diff(raster.mean(axis=-1), axis=axis)) > 0.08
        pad = [(0, 0), (0, 0)]
        pad[axis] = (1, 0)
        smooth &= ~np.pad(jump, pad) & ~np.pad(jump, [(b, a) for a, b in pad])
    compared = erode(pane) & smooth & np.isfinite(depth)
    assert compared.sum() > 0.2 * pane.size
    difference = np.abs(traced - raster).max(axis=-1)
    tolerance = 0.01 + 0.03 * raster.max(axis=-1)
    agree = np.mean(difference[compared] <= tolerance[compared])
    assert agree > 0.995, f"traced and raster agree on {agree:.2%} of the pane (max diff {difference[compared].max()})"


def shadow_scene():
    """A floor and four casters side by side under an oblique sun: an opaque box, a 30%
    transmissive curtain (casts), an alpha-0.3 card and a clear glass box (do not)."""
    scene = showcase.empty_scene(WIDTH, HEIGHT)
    scene.phrt.shadow_map_size = 1024
    set_world(scene, (0.0, 0.0, 0.0))
    showcase.mesh_object("Floor", showcase.plane(12.0), showcase.principled("Floor", (0.7, 0.7, 0.7), roughness=1.0))
    casters = {
        "Opaque": showcase.principled("Opaque", (0.6, 0.3, 0.2)),
        "Curtain": showcase.principled("Curtain", (0.3, 0.5, 0.8), transmission=0.3),
        "Card": showcase.principled("Card", (0.9, 0.1, 0.1), alpha=0.3),
        "Glass": showcase.principled("Glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.5),
    }
    boxes = {}
    for index, (name, material) in enumerate(casters.items()):
        x = -2.25 + 1.5 * index
        low, high = np.array([x - 0.4, 0.2, 0.9]), np.array([x + 0.4, 0.8, 1.3])
        obj = showcase.mesh_object(name, showcase.cube(1.0), material, location=tuple((low + high) / 2),
                                   scale=tuple(high - low))
        showcase.tag(obj, shadows=True, reflections=False, refractions=False)
        boxes[name] = (low, high)
    sun = showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(np.radians(-40.0), 0.0, 0.0), name="Sun")
    sun.data.angle = 0.0
    showcase.add_camera((0.0, -4.0, 4.5), (0.0, 0.3, 0.0), lens=24.0)
    return scene, boxes


def test_what_casts_a_shadow_is_one_rule_for_shadow_maps_and_shadow_rays(tmp_path):
    scene, boxes = shadow_scene()
    origins, directions = camera_rays()
    floor_t = plane_hit(origins, directions, 0.0)
    points = origins + directions * floor_t[..., None]
    to_sun = np.array(bpy.data.objects["Sun"].matrix_world, float)[:3, 2]
    covered = np.zeros(points.shape[:2], bool)
    shadow_of = {}
    for name, (low, high) in boxes.items():
        covered |= np.isfinite(box_hit(origins, directions, low - 0.02, high + 0.02))
        shadow_of[name] = np.isfinite(box_hit(points + to_sun * 1e-6, np.broadcast_to(to_sun, points.shape),
                                              low, high))
    floor = np.isfinite(floor_t) & ~covered
    for mode in ("RASTER", "RAYTRACE"):
        image = render(scene, mode, "casters", tmp_path)["Combined"][..., :3].mean(axis=-1)
        lit_level = np.percentile(image[floor], 95)
        for name, casts in (("Opaque", True), ("Curtain", True), ("Card", False), ("Glass", False)):
            region = erode(shadow_of[name], 2) & floor
            assert region.sum() > 30, name
            assert rules.casts_shadow(_material(name)) == casts
            dark = np.mean(image[region] < 0.5 * lit_level)
            if casts:
                assert dark > 0.97, f"{mode}: {name} should cast a shadow ({dark:.1%} dark)"
            else:
                assert dark < 0.03, f"{mode}: {name} should cast no shadow ({dark:.1%} dark)"
        if mode == "RAYTRACE":
            assert selected_elements() == set(boxes)


def _material(name):
    from phrt.engine import extract
    return extract.read_material(bpy.data.materials[name], [])


def test_k_zero_is_neither_selected_nor_marked_as_candidate(tmp_path):
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    scene.phrt.shadow_map_size = 256
    bpy.data.objects["MirrorSphere"].phrt.priority = 0.0
    passes = render(scene, "RAYTRACE", "k-zero", tmp_path)
    rows = {row["element"]: row for row in session.last_frame().rows}
    assert rows["MirrorSphere"]["reason"] == "not_candidate" and not rows["MirrorSphere"]["selected"]
    assert rows["GlassSlab"]["selected"]
    sphere = passes["PHRT Selected"] < 0.5
    # The sphere's pixels: the front-most element in the middle of its image.
    origins, directions = camera_rays()
    centre = np.array(bpy.data.objects["MirrorSphere"].location)
    relative = origins - centre
    b = np.sum(relative * directions, axis=-1)
    hits_sphere = b * b - (np.sum(relative * relative, axis=-1) - 0.65 ** 2) > 0
    assert hits_sphere.sum() > 50
    assert np.all(passes["PHRT Candidate"][hits_sphere] == 0.0)
    assert np.all(sphere[hits_sphere])
    glass = passes["PHRT Selected"] > 0.5
    assert np.all(passes["PHRT Candidate"][glass] == 1.0)
    assert session.last_frame().stats["n_candidates"] == 2  # glass slab and fence


def mirror_and_glass_scene(max_bounces):
    """A mirror sphere and a closed glass block over a warm floor, a saturated blue world."""
    scene = showcase.empty_scene(WIDTH, HEIGHT)
    scene.phrt.shadow_map_size = 256
    scene.phrt.max_bounces = max_bounces
    assert scene.phrt.max_bounces == max_bounces  # 32 is allowed, not clamped by the property
    set_world(scene, (0.0, 0.0, 1.0))
    showcase.mesh_object("Floor", showcase.plane(10.0), showcase.principled("Floor", (0.8, 0.7, 0.5), roughness=1.0))
    mirror = showcase.mesh_object("Mirror", showcase.sphere(0.6, 32, 16),
                                  showcase.principled("Mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0),
                                  location=(-0.8, 0.0, 0.6), smooth=True)
    glass = showcase.mesh_object("Block", showcase.cube(1.0), showcase.principled(
        "Glass", (1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.5), location=(0.9, 0.0, 0.6),
        scale=(0.9, 0.9, 0.9))
    for obj in (mirror, glass):
        showcase.tag(obj, shadows=False, reflections=True, refractions=True)
    showcase.add_light("SUN", (0, 0, 5), 3.0, rotation=(np.radians(30), 0.0, np.radians(20)), name="Sun")
    showcase.add_camera((0.0, -4.0, 2.2), (0.0, 0.0, 0.5), lens=35.0)
    return scene


def test_max_bounces_zero_traces_no_bounce(tmp_path):
    """0 = no reflection or refraction ray: the selected mirror and glass look as rastered."""
    scene = mirror_and_glass_scene(0)
    raster = render(scene, "RASTER", "bounces-0", tmp_path)["Combined"]
    traced = render(scene, "RAYTRACE", "bounces-0", tmp_path)
    assert selected_elements() == {"Mirror", "Block"}
    assert session.last_frame().stats["reflection_rays"] == 0 and session.last_frame().stats["refraction_rays"] == 0
    np.testing.assert_array_equal(traced["Combined"], raster)


@pytest.mark.parametrize("max_bounces", [1, 32])
def test_one_bounce_and_more_see_the_floor_through_closed_glass(max_bounces, tmp_path):
    """1 = one traced bounce: the refraction ray into the block cannot refract again at its far
    side, so the light goes straight on to the floor (never the blue world colour)."""
    scene = mirror_and_glass_scene(max_bounces)
    traced = render(scene, "RAYTRACE", f"bounces-{max_bounces}", tmp_path)
    stats = session.last_frame().stats
    assert stats["reflection_rays"] > 0 and stats["refraction_rays"] > 0
    selected = traced["PHRT Selected"] > 0.5
    block = selected.copy()
    block[:, : WIDTH // 2] = False  # the block is the selected element on the right
    assert block.sum() > 300
    color = traced["Combined"][..., :3][block]
    red_share = color[:, 0] / np.maximum(color.sum(axis=1), 1e-6)
    floor_like = np.mean(red_share > 0.2)  # the warm floor; the world is pure blue (red share 0)
    assert floor_like > 0.4, f"max_bounces {max_bounces}: {floor_like:.0%} of the block shows the floor"
