"""Stiff and extreme cases of the tracer and the frame after the G-buffer, without Blender:
a white furnace (a clear glass sphere in a uniform world must vanish, total internal
reflection at its rim included), IOR 1 and the clamped IORs, alpha cards, the meaning of
max_bounces, grazing mirrors at 89.9 degrees, millimetre props beside a mountain 1e5 units
away (precision clusters), secondary rays leaving along the geometric normal (no terminator
acne at the silhouette of a coarse smooth sphere), and no NaN/Inf anywhere."""
import numpy as np
import pytest

from phrt.phrt_addon.scene import rules, shading
from phrt.phrt_addon.raster import shadowmap
from phrt.phrt_addon.trace import embree_scene, tracer
from phrt.phrt_addon.frame import FrameRenderer
from phrt.phrt_addon.raster.reference_raster import ReferenceRaster
from phrt.phrt_addon.raster.gbuffer import GBuffer, GBufferLayer
from phrt.phrt_addon.raster.normals import geometric_normals
from phrt.phrt_addon.scene.snapshot import Camera, Element, Light, Material, SceneSnapshot, Settings

from test_tracer import (GLASS, MIRROR, box, build, diffuse, emissive, quad, snapshot, translation,  # noqa: E402
                         uv_sphere)

WORLD = (0.2, 0.5, 0.8)


def rays_at_sphere(centre, radius, count=4000, eye=(0.0, -5.0, 0.0), seed=1):
    """Rays from ``eye`` at points spread over the sphere's disc as seen from there, with many
    close to the rim (where refraction inside ends in total internal reflection)."""
    rng = np.random.default_rng(seed)
    eye = np.asarray(eye, float)
    axis = shading.normalize(np.asarray(centre, float) - eye)
    across = shading.normalize(np.cross(axis, [0.0, 0.0, 1.0]))
    up = np.cross(across, axis)
    radial = np.sqrt(rng.uniform(0.0, 1.0, count))
    radial[: count // 4] = 1.0 - rng.uniform(0.0, 0.02, count // 4)  # the rim
    angle = rng.uniform(0.0, 2 * np.pi, count)
    targets = np.asarray(centre) + radius * 0.999 * radial[:, None] * (
        np.cos(angle)[:, None] * across + np.sin(angle)[:, None] * up)
    return np.tile(eye, (count, 1)), shading.normalize(targets - eye)


@pytest.mark.parametrize("ior", [1.0, 1.5, 2.4, 4.0, 11.0, 0.5])
@pytest.mark.parametrize("max_bounces", [1, 4, 32])
def test_clear_glass_sphere_vanishes_in_a_white_furnace(ior, max_bounces, closing):
    """No lights, a uniform world: whatever the glass does (Fresnel, refraction, total internal
    reflection at the rim, running out of bounces) it neither creates nor loses light."""
    glass = Material("glass", base_color=(1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=ior)
    snap = snapshot([uv_sphere("ball", (0, 0, 0), 1.0, 48, 24)], [glass], world=WORLD, max_bounces=max_bounces)
    scene, radiance_tracer = build(snap)
    closing(scene)
    origins, directions = rays_at_sphere((0, 0, 0), 1.0)
    color = radiance_tracer.radiance(scene.to_trace(origins), directions, 0)
    assert radiance_tracer.rays > len(origins)  # the glass was hit and traced through
    np.testing.assert_allclose(color, np.broadcast_to(WORLD, color.shape), rtol=1e-6, atol=1e-9)


def lit_checker_scene(glass=None, lights=True):
    """An emissive-free diffuse checker floor lit by a sun (plus a dim world), optionally with a
    glass block over it."""
    materials = [diffuse("light", (0.8, 0.8, 0.8)), diffuse("dark", (0.1, 0.1, 0.1))]
    meshes = []
    for i in range(8):
        for j in range(8):
            meshes.append(quad(f"tile{i}{j}", (i - 3.5, j - 3.5, 0.0), 1.0, 1.0, "+z", material=(i + j) % 2))
    if glass is not None:
        materials.append(glass)
        meshes.append(box("glass", (-2, -2, 0.5), (2, 2, 1.5), material=2))
    sun = Light("sun", "SUN", (3.0, 3.0, 3.0), direction=tuple(shading.normalize(np.array([0.3, 0.2, -1.0]))))
    return snapshot(meshes, materials, [sun] if lights else [], world=(0.05, 0.05, 0.05))


def floor_rays(count=3000, seed=2):
    rng = np.random.default_rng(seed)
    eye = np.array([0.3, -6.0, 5.0])
    targets = np.c_[rng.uniform(-1.9, 1.9, (count, 2)), np.zeros(count)]
    return np.tile(eye, (count, 1)), shading.normalize(targets - eye)


@pytest.mark.parametrize("ior", [1.0, 0.7])
def test_glass_of_ior_one_or_below_vanishes_exactly(ior, closing):
    """IOR 1 bends and reflects nothing and lets all light through (no shadow): the floor seen
    through the block is the floor seen without it.  An IOR below 1 is clamped to 1."""
    glass = Material("glass", base_color=(1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=ior)
    origins, directions = floor_rays()
    results = []
    for snap in (lit_checker_scene(), lit_checker_scene(glass)):
        scene, radiance_tracer = build(snap)
        closing(scene)
        results.append(radiance_tracer.radiance(scene.to_trace(origins), directions, 0))
    assert results[0].max() > 0.5 and results[0].min() < 0.2  # lit tiles of both colours
    np.testing.assert_allclose(results[1], results[0], rtol=1e-5, atol=1e-7)


def test_ior_above_the_limit_renders_like_the_limit(closing):
    origins, directions = floor_rays()
    results = []
    for ior in (rules.MAX_IOR, 11.0, 1e6):
        glass = Material("glass", base_color=(1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=ior)
        scene, radiance_tracer = build(lit_checker_scene(glass))
        closing(scene)
        results.append(radiance_tracer.radiance(scene.to_trace(origins), directions, 0))
    np.testing.assert_array_equal(results[1], results[0])
    np.testing.assert_array_equal(results[2], results[0])


def test_alpha_card_blends_what_it_shows_with_what_is_behind(closing):
    """A red emissive card with alpha 0.25 before a green emissive wall: a quarter red, three
    quarters green, in the tracer as in the raster composite."""
    card = Material("card", base_color=(0.0, 0.0, 0.0), roughness=1.0, emission=(1.0, 0.0, 0.0), alpha=0.25)
    snap = snapshot([quad("card", (0, 0, 1), 2, 2, "-z", material=0), quad("wall", (0, 0, 3), 20, 20, "-z",
                                                                             material=1)],
                    [card, emissive("green", (0.0, 1.0, 0.0))])
    scene, radiance_tracer = build(snap)
    closing(scene)
    color = radiance_tracer.radiance(scene.to_trace([[0.1, 0.2, 0.0]]), np.array([[0.0, 0.0, 1.0]]), 0)[0]
    np.testing.assert_allclose(color, [0.25, 0.75, 0.0], atol=1e-6)


@pytest.mark.parametrize("alpha,shadowed", [(0.25, False), (0.8, True)])
def test_alpha_card_casts_a_shadow_by_the_shadow_rule(alpha, shadowed, closing):
    card = Material("card", alpha=alpha)
    snap = snapshot([quad("floor", (0, 0, 0), 10, 10, "+z", material=0), quad("card", (0, 0, 1), 2, 2, "+z",
                                                                              material=1)],
                    [diffuse("floor"), card])
    scene, _ = build(snap)
    closing(scene)
    blocked = scene.occluded(scene.to_trace([[0.0, 0.0, 1e-3]]), np.array([[0.0, 0.0, 1.0]]), np.array([10.0]))[0]
    assert blocked == shadowed == rules.casts_shadow(card)


def closed_glass_over_floor(max_bounces):
    materials = [GLASS, emissive("green", (0.0, 1.0, 0.0))]
    meshes = [box("glass", (-1, -1, 0.5), (1, 1, 1.5), material=0), quad("floor", (0, 0, 0), 20, 20, "+z",
                                                                         material=1)]
    return snapshot(meshes, materials, world=(0.0, 0.0, 1.0), max_bounces=max_bounces)


@pytest.mark.parametrize("max_bounces", [1, 2, 32])
def test_one_bounce_through_closed_glass_sees_the_floor_not_the_world(max_bounces, closing):
    """A ray leaving the G-buffer into glass is bounce 1.  With max_bounces 1 it cannot refract
    again at the far side: the light goes straight on (the raster's blend), to the floor."""
    scene, radiance_tracer = build(closed_glass_over_floor(max_bounces))
    closing(scene)
    directions = shading.normalize(np.array([[0.2, 0.1, -1.0], [0.0, 0.0, -1.0], [-0.3, 0.2, -1.0]]))
    origins = np.array([[0.0, 0.0, 1.5 + 1e-4]])
    color = radiance_tracer.radiance(scene.to_trace(origins - directions * 0.5), directions, 1)
    assert np.all(color[:, 1] > 0.8), color  # (1 - F)^2 of the green floor
    assert np.all(color[:, 2] < 0.15), color  # only Fresnel reflections of the blue world


def test_max_bounces_32_between_parallel_mirrors_traces_33_rays(closing):
    snap = snapshot([quad("a", (0, 0, 0), 10, 10, "+z"), quad("b", (0, 0, 1), 10, 10, "-z")], [MIRROR],
                    world=(0.25, 0.5, 1.0), max_bounces=32)
    scene, radiance_tracer = build(snap)
    closing(scene)
    color = radiance_tracer.radiance(scene.to_trace([[0.0, 0.0, 0.5]]), np.array([[0.01, 0.0, 1.0]]), 0)
    assert radiance_tracer.rays == 33
    np.testing.assert_allclose(color[0], [0.25, 0.5, 1.0], rtol=1e-6)


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
@pytest.mark.parametrize("offset", [0.0, 1e5])
def test_mirror_at_89_9_degrees_reflects_the_sky_and_never_itself(scale, offset, closing):
    """Rays meeting a mirror floor 0.1 degrees above grazing come back up to a blue sky: none
    may hit its own surface (black) or go through it."""
    materials = [MIRROR, emissive("sky", (0.0, 0.0, 1.0)), emissive("below", (1.0, 0.0, 0.0))]
    meshes = [quad("mirror", (0, 0, 0), 4000 * scale, 4000 * scale, "+z", material=0),
              quad("sky", (0, 0, 5 * scale), 1e6 * scale, 1e6 * scale, "-z", material=1),
              quad("below", (0, 0, -5 * scale), 1e6 * scale, 1e6 * scale, "+z", material=2)]
    for instance in meshes:
        instance.matrix_world = translation((offset, offset, offset))
    scene, radiance_tracer = build(snapshot(meshes, materials))
    closing(scene)
    elevation = np.radians(0.1)
    azimuth = np.linspace(0.0, 2 * np.pi, 360, endpoint=False)
    directions = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                           np.full_like(azimuth, -np.sin(elevation))], axis=1)
    hit_points = np.c_[np.cos(azimuth + 1.0), np.sin(azimuth + 1.0), np.zeros_like(azimuth)] * 100 * scale
    eyes = hit_points - directions * 300 * scale + offset
    color = radiance_tracer.radiance(scene.to_trace(eyes), directions, 0)
    np.testing.assert_allclose(color[:, 2], 1.0, rtol=1e-5)
    assert np.all(color[:, 0] < 1e-6)


def tiny_shadow_scene(with_mountain):
    """Millimetre props near the origin (a floor of 6 mm, a 1 mm box on it, a sun), and, far
    away, a mountain 1e3 units wide at 1e5: one snapshot, both scales."""
    floor = quad("floor", (0, 0, 0), 6e-3, 6e-3, "+z", material=0)
    cube = box("box", (-5e-4, -5e-4, 0.0), (5e-4, 5e-4, 1e-3), material=0)
    meshes = [floor, cube]
    if with_mountain:
        meshes.append(box("mountain", (1e5, 1e5, 0.0), (1e5 + 1e3, 1e5 + 1e3, 1e3), material=0))
    sun = Light("sun", "SUN", (1.0, 1.0, 1.0), direction=tuple(shading.normalize(np.array([-1.0, -0.3, -1.0]))))
    return snapshot(meshes, [diffuse("grey")], [sun])


def test_millimetre_props_keep_their_shadows_beside_a_mountain_1e5_away(closing):
    rng = np.random.default_rng(9)
    targets = np.c_[rng.uniform(-2.9e-3, 2.9e-3, (20000, 2)), np.zeros(20000)]
    eye = np.array([4e-3, -6e-3, 5e-3])
    directions = shading.normalize(targets - eye)
    colors, clusters = [], []
    for with_mountain in (False, True):
        scene, radiance_tracer = build(tiny_shadow_scene(with_mountain))
        closing(scene)
        colors.append(radiance_tracer.radiance(scene.to_trace(np.tile(eye, (len(targets), 1))), directions, 0))
        clusters.append(scene.stats["clusters"])
    assert clusters == [1, 2]
    shadowed = colors[0][:, 0] < 1e-6
    assert 0.02 < shadowed.mean() < 0.5  # the box casts a shadow on the floor
    np.testing.assert_array_equal(colors[1][:, 0] < 1e-6, shadowed)  # no acne, no leak
    np.testing.assert_allclose(colors[1], colors[0], rtol=1e-4, atol=1e-9)


def test_precision_clusters_keep_each_mesh_close_to_its_origin():
    lows = np.array([[-1e-3, -1e-3, 0], [-10, -10, 0], [1e5, 1e5, 0], [1e5 + 5, 1e5, 0]])
    highs = lows + np.array([[2e-3, 2e-3, 1e-3], [20, 20, 0], [1e3, 1e3, 1e3], [1, 1, 1]])
    origins, extents, cluster = embree_scene.precision_clusters(lows, highs)
    centres, sizes = (lows + highs) / 2, np.max(highs - lows, axis=1)
    reach = np.max(np.abs(centres - origins[cluster]), axis=1) + sizes / 2
    assert np.all(reach <= embree_scene.PRECISION_RATIO * sizes)
    assert cluster[0] != cluster[2] and cluster[2] == cluster[3]
    assert len(origins) <= embree_scene.MAX_CLUSTERS and np.all(extents > 0)


def test_secondary_directions_are_bent_out_of_the_geometric_surface():
    normal = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    below = shading.normalize(np.array([[1.0, 0.0, -0.05], [0.0, 1.0, 0.3]]))
    fixed = tracer.leave_surface(below, normal)
    assert np.all(shading.dot(fixed, normal) >= tracer.MIN_LEAVING_COSINE * 0.99)
    np.testing.assert_array_equal(fixed[1], below[1])  # already leaving: untouched
    inward = tracer.leave_surface(below, normal, side=-1.0)
    assert np.all(shading.dot(inward, normal) < 0)


# -- the frame after the G-buffer, with a G-buffer made by ray casting ---------------------------------

def look_at_camera(eye, target, width, height, fov=np.radians(40.0)):
    view = shadowmap.look_at(np.asarray(target, float) - np.asarray(eye, float))
    matrix_world = np.linalg.inv(view)
    matrix_world[:3, 3] = eye
    projection = shadowmap.perspective(fov, 0.05, 100.0)
    projection[0, 0] *= height / width
    return Camera(matrix_world=matrix_world, projection=projection, width=width, height=height, clip_start=0.05,
                  clip_end=100.0)


def raycast_gbuffer(snap):
    """The G-buffer the GPU would draw, by tracing one camera ray per pixel centre: positions
    relative to the camera, interpolated (shading) normals as authored, ids, roughness."""
    camera = snap.camera
    scene = embree_scene.TraceScene(threads=1)
    try:
        scene.update(snap)
        origins, directions = camera.pixel_rays()
        origins = np.broadcast_to(camera.position, origins.shape).reshape(-1, 3)
        directions = directions.reshape(-1, 3)
        hits = scene.intersect(scene.to_trace(origins), directions)
        hit = np.isfinite(hits["t"])
        idx, material, element, normal, _, _, _ = scene.hit_surfaces(hits, hit)
    finally:
        scene.close()
    layer = GBufferLayer.empty(camera.width, camera.height)
    flat = np.flatnonzero(hit)
    table = shading.MaterialTable(snap.materials)
    layer.covered.ravel()[flat] = True
    layer.position.reshape(-1, 3)[flat] = directions[flat] * hits["t"][flat, None]
    layer.normal.reshape(-1, 3)[flat] = normal
    layer.roughness.ravel()[flat] = table.roughness[material]
    layer.albedo.reshape(-1, 3)[flat] = table.base_color[material]
    layer.metallic.ravel()[flat] = table.metallic[material]
    layer.material.ravel()[flat] = material
    layer.element.ravel()[flat] = element
    view_depth = np.full((camera.height, camera.width), np.inf, np.float32)
    view_depth.ravel()[flat] = (layer.position.reshape(-1, 3)[flat] @ camera.forward)
    return GBuffer(opaque=layer, transparent=GBufferLayer.empty(camera.width, camera.height),
                   origin=camera.position, view_depth=view_depth)


def coarse_sphere_snapshot(mode, shadows=True):
    """A coarse smooth sphere (12 x 6: interpolated normals far from the facets) lit by a sun from
    beside the camera, so its silhouette is lit; nothing else can shadow it."""
    sphere = uv_sphere("ball", (0, 0, 0), 1.0, 12, 6, material=0, element=0)
    camera = look_at_camera(np.array([0.0, -4.0, 0.0]), np.zeros(3), 96, 72)
    sun = Light("sun", "SUN", (2.0, 2.0, 2.0), direction=tuple(shading.normalize(np.array([0.15, 1.0, -0.1]))))
    element = Element("ball", "ball", shadows=shadows, reflections=False, refractions=False)
    return SceneSnapshot(meshes=[sphere], materials=[diffuse("grey", (0.7, 0.7, 0.7))], elements=[element],
                         lights=[sun], camera=camera, world_color=(0.02, 0.02, 0.02),
                         settings=Settings(mode=mode, budget_ms=1e9, max_bounces=2))


def test_traced_self_shadow_of_a_convex_coarse_sphere_has_no_acne_at_its_silhouette():
    """A convex object cannot shadow itself where it faces the light: traced shadows must leave
    the raster image (no shadow maps: fully lit) as it is on every pixel.  Secondary rays offset
    along the interpolated normal - flipped towards the camera at the silhouette - start inside
    the sphere there and come back shadowed."""
    images = {}
    for mode in ("RASTER", "RAYTRACE"):
        snap = coarse_sphere_snapshot(mode)
        renderer = FrameRenderer(threads=1)
        try:
            result = renderer.render(snap, ReferenceRaster(snap, raycast_gbuffer(snap)))
        finally:
            renderer.close()
        images[mode] = result.passes.combined[..., :3]
        assert np.all(np.isfinite(result.passes.combined))
    assert result.stats["n_selected"] == 1 and result.stats["shadow_rays"] > 1000
    lit = images["RASTER"].mean(axis=-1) > 0.05
    assert lit.sum() > 1000
    np.testing.assert_allclose(images["RAYTRACE"], images["RASTER"], atol=1e-6)


def test_geometric_normals_of_the_gbuffer_are_the_facets():
    snap = coarse_sphere_snapshot("RAYTRACE")
    gbuffer = raycast_gbuffer(snap)
    layer = gbuffer.opaque
    flat = np.flatnonzero(layer.covered.ravel())
    directions = shading.normalize(layer.position.reshape(-1, 3)[flat].astype(np.float64))
    normals = geometric_normals(layer, flat, directions)
    # Facet normals of the sphere: the ray cast's own Ng at those pixels.
    scene = embree_scene.TraceScene(threads=1)
    try:
        scene.update(snap)
        hits = scene.intersect(scene.to_trace(np.broadcast_to(snap.camera.position, directions.shape)), directions)
        facets = shading.normalize(hits["Ng"].astype(np.float64))
    finally:
        scene.close()
    facets *= np.where(shading.dot(facets, directions) > 0, -1.0, 1.0)[:, None]
    agreement = shading.dot(normals, facets)
    assert np.mean(agreement > 0.999) > 0.8  # inside facets: exact
    assert np.all(shading.dot(normals, -directions) > 0)  # always on the camera's side
