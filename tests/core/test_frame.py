"""``FrameRenderer`` on hand-built G-buffers, without Blender: the raster half is the numpy
reference (``lighting.ReferenceRaster``), the G-buffer is ray cast with Embree.

Pins: RASTER never builds an Embree scene; a selected mirror shows the red wall it faces
where RASTER shows the environment; no lights means no shadow rays; the Candidate pass
leaves out K = 0 elements; every pass is finite."""
import numpy as np
import pytest

from phrt.phrt_addon.scene import shading
from phrt.phrt_addon.raster import shadowmap
from phrt.phrt_addon.frame import FrameRenderer
from phrt.phrt_addon.frame_types import LayerPixels
from phrt.phrt_addon.raster.gbuffer import GBuffer, GBufferLayer
from phrt.phrt_addon.raster.reference_raster import ReferenceRaster
from phrt.phrt_addon.scene.snapshot import Camera, Element, Light, Material, SceneSnapshot, Settings
from phrt.phrt_addon.trace.embree_scene import TraceScene

from test_tracer import box, quad

WIDTH, HEIGHT = 96, 72


def camera(position, target, fov=np.radians(60.0)):
    view = shadowmap.look_at(np.subtract(target, position))
    view[:3, 3] = -(view[:3, :3] @ np.asarray(position, float))
    return Camera(matrix_world=np.linalg.inv(view), projection=shadowmap.perspective(fov, 0.1, 100.0),
                  width=WIDTH, height=HEIGHT, clip_start=0.1, clip_end=100.0)


def mirror_scene(mode, lights=True, mirror_priority=1.0):
    """A floor, a mirror patch on it (element 0) facing a red wall, a matte block (element 1)."""
    materials = [Material("Floor", base_color=(0.5, 0.5, 0.5), roughness=0.8),
                 Material("Mirror", base_color=(0.95, 0.95, 0.95), metallic=1.0, roughness=0.0),
                 Material("Red", base_color=(0.9, 0.05, 0.05), roughness=0.9, emission=(2.0, 0.0, 0.0)),
                 Material("Matte", base_color=(0.3, 0.4, 0.5), roughness=0.9)]
    elements = [Element("Mirror", "Mirror", priority=mirror_priority, shadows=False, reflections=True,
                        refractions=False),
                Element("Block", "Block", priority=1.0, shadows=True, reflections=False, refractions=False)]
    meshes = [quad("Floor", (0, 0, 0), 20, 20, "+z", material=0),
              quad("Mirror", (0, 1.0, 0.01), 2.0, 2.0, "+z", material=1, element=0),
              quad("Wall", (0, 4.0, 1.5), 8.0, 3.0, "-y", material=2),
              box("Block", (1.5, -0.5, 0.0), (2.3, 0.3, 0.8), material=3, element=1)]
    scene_lights = [Light("Sun", "SUN", (3.0, 3.0, 3.0), direction=(0.3, 0.4, -1.0))] if lights else []
    return SceneSnapshot(meshes=meshes, materials=materials, elements=elements, lights=scene_lights,
                         camera=camera((0.0, -4.0, 2.5), (0.0, 1.0, 0.0)), world_color=(0.05, 0.05, 0.08),
                         settings=Settings(mode=mode, budget_ms=1e6))


def ray_cast_gbuffer(snapshot) -> GBuffer:
    """The opaque layer by primary rays (what the GPU rasterizes), positions relative to the camera."""
    scene = TraceScene(threads=1)
    try:
        scene.update(snapshot)
        origins, directions = snapshot.camera.pixel_rays()
        origins = origins.reshape(-1, 3)
        directions = directions.reshape(-1, 3)
        hits = scene.intersect(scene.to_trace(origins), directions)
        hit = np.isfinite(hits["t"])
        idx, material, element, normal, _, _, _ = scene.hit_surfaces(hits, hit)
    finally:
        scene.close()
    layer = GBufferLayer.empty(WIDTH, HEIGHT)
    layer.albedo = np.zeros((HEIGHT, WIDTH, 3), np.float32)
    layer.metallic = np.zeros((HEIGHT, WIDTH), np.float32)
    flat = np.flatnonzero(hit)[np.arange(len(idx))]
    world = origins[flat] + directions[flat] * hits["t"][flat, None]
    table = shading.MaterialTable(snapshot.materials)
    facing = np.where((np.sum(normal * directions[flat], axis=1) > 0)[:, None], -normal, normal)
    for name, values in (("position", world - snapshot.camera.position), ("normal", facing),
                         ("albedo", table.base_color[material])):
        getattr(layer, name).reshape(-1, 3)[flat] = values
    layer.covered.ravel()[flat] = True
    layer.roughness.ravel()[flat] = table.roughness[material]
    layer.metallic.ravel()[flat] = table.metallic[material]
    layer.material.ravel()[flat] = material
    layer.element.ravel()[flat] = element
    depth = np.full((HEIGHT, WIDTH), np.inf, np.float32)
    depth.ravel()[flat] = (world - snapshot.camera.position) @ snapshot.camera.forward
    return GBuffer(opaque=layer, transparent=GBufferLayer.empty(WIDTH, HEIGHT), origin=snapshot.camera.position,
                   view_depth=depth)


def render(snapshot, renderer=None):
    renderer = renderer or FrameRenderer(threads=1)
    try:
        gbuffer = ray_cast_gbuffer(snapshot)
        return renderer.render(snapshot, ReferenceRaster(snapshot, gbuffer)), gbuffer, renderer
    finally:
        renderer.close()


def test_raster_mode_builds_no_embree_scene_and_traces_no_ray():
    result, _, renderer = render(mirror_scene("RASTER"))
    assert renderer.trace_scene is None
    assert result.stats["rays"] == 0 and result.stats["readback_ms"] == 0.0
    assert result.stats["n_visible"] == 2 and result.stats["n_selected"] == 0


def test_the_first_frame_that_may_trace_builds_the_embree_scenes_as_set_up():
    """A replay's first frame with a visible candidate builds the Embree scenes (one-time work,
    in its set-up) even when it traces nothing; the first frame that traces then builds none."""
    tight = mirror_scene("HYBRID")
    tight.settings = Settings(mode="HYBRID", budget_ms=1e-3)  # no time left: nothing selected
    renderer = FrameRenderer(threads=1)
    try:
        first = renderer.render(tight, ReferenceRaster(tight, ray_cast_gbuffer(tight)))
        assert first.stats["n_selected"] == 0 and first.stats["rays"] == 0
        assert renderer.trace_scene is not None and renderer.trace_scene.stats["static_builds"] == 1
        assert 0 < first.stats["upload_ms"] <= first.stats["setup_ms"]
        assert first.stats["upload_ms"] <= first.stats["trace_ms"] <= first.stats["total_ms"]
        renderer.forced_selection = frozenset({"Mirror", "Block"})
        second = renderer.render(tight, ReferenceRaster(tight, ray_cast_gbuffer(tight)))
        assert second.stats["reflection_rays"] > 0 and second.stats["shadow_rays"] > 0
        assert second.stats["upload_ms"] == 0.0 and renderer.trace_scene.stats["static_builds"] == 1
    finally:
        renderer.close()


def test_a_later_first_frame_that_may_trace_builds_and_traces_at_once():
    """A renderer that drew RASTER frames first builds the Embree scenes on its first frame that
    may trace, which here traces too: one build, counted once as set-up."""
    renderer = FrameRenderer(threads=1)
    try:
        raster = mirror_scene("RASTER")
        renderer.render(raster, ReferenceRaster(raster, ray_cast_gbuffer(raster)))
        assert renderer.trace_scene is None
        hybrid = mirror_scene("HYBRID")
        renderer.forced_selection = frozenset({"Mirror"})
        result = renderer.render(hybrid, ReferenceRaster(hybrid, ray_cast_gbuffer(hybrid)))
        assert result.stats["reflection_rays"] > 0 and renderer.trace_scene.stats["static_builds"] == 1
        assert 0 < result.stats["upload_ms"] <= result.stats["setup_ms"]
        assert result.stats["upload_ms"] <= result.stats["trace_ms"]
    finally:
        renderer.close()


def test_selected_mirror_shows_the_red_wall_where_raster_shows_the_environment():
    raster, gbuffer, _ = render(mirror_scene("RASTER"))
    traced, _, _ = render(mirror_scene("RAYTRACE"))
    mirror = gbuffer.opaque.element == 0
    assert mirror.sum() > 100
    assert traced.stats["n_selected"] == 2 and traced.stats["reflection_rays"] > 0
    raster_mirror = raster.passes.combined[mirror][:, :3]
    traced_mirror = traced.passes.combined[mirror][:, :3]
    assert np.median(traced_mirror[:, 0]) > 5 * np.median(traced_mirror[:, 1])  # red
    assert np.median(raster_mirror[:, 0]) < 2 * np.median(raster_mirror[:, 2])  # the bluish world
    # Outside the traced elements the two frames agree exactly except where the block's traced
    # shadow replaced the shadow map.
    away = ~mirror & (gbuffer.opaque.element != 1)
    same = np.isclose(raster.passes.combined[away], traced.passes.combined[away], rtol=1e-5, atol=1e-6)
    assert same.all(axis=-1).mean() > 0.8
    assert traced.passes.selected[mirror].min() == 1.0


def test_no_lights_means_no_shadow_rays_even_with_a_selected_caster():
    result, _, _ = render(mirror_scene("RAYTRACE", lights=False))
    assert result.stats["n_selected"] == 2
    assert result.stats["shadow_rays"] == 0


@pytest.mark.parametrize("mode", ["RASTER", "HYBRID", "RAYTRACE"])
def test_passes_are_finite_and_the_candidate_pass_leaves_out_k_zero(mode):
    result, gbuffer, _ = render(mirror_scene(mode, mirror_priority=0.0))
    for name in ("combined", "depth", "normal", "selected", "candidate"):
        assert np.isfinite(getattr(result.passes, name)).all(), name
    mirror = gbuffer.opaque.element == 0
    block = gbuffer.opaque.element == 1
    assert result.passes.candidate[mirror].max() == 0.0
    assert result.passes.candidate[block].min() == 1.0
    assert result.passes.selected[mirror].max() == 0.0


@pytest.mark.parametrize("step", [1, 8])
def test_front_points_from_view_depth_are_the_gbuffer_positions(step):
    """The shadow-footprint estimate reads no layer back: it rebuilds sampled world positions
    from the resolve's view depth."""
    from phrt.phrt_addon.raster.gbuffer import front_points
    snapshot = mirror_scene("HYBRID")
    gbuffer = ray_cast_gbuffer(snapshot)
    points = front_points(snapshot.camera, gbuffer.view_depth, step)
    rows = np.arange(step // 2, HEIGHT, step)
    cols = np.arange(step // 2, WIDTH, step)
    position = gbuffer.opaque.position[np.ix_(rows, cols)].reshape(-1, 3)
    covered = gbuffer.opaque.covered[np.ix_(rows, cols)].ravel()
    expected = position[covered].astype(np.float64) + snapshot.camera.position
    assert len(points) == covered.sum() > 20
    np.testing.assert_allclose(points, expected, atol=1e-3)


def test_front_points_with_a_kept_grid_follow_the_frame_size_and_step():
    """A replay keeps the sub-sample's NDC (PixelGrid); a kept grid of another size or step would
    put every point elsewhere."""
    from phrt.phrt_addon.raster.gbuffer import PixelGrid, front_points
    snapshot = mirror_scene("HYBRID")
    depth = ray_cast_gbuffer(snapshot).view_depth
    grid = PixelGrid()
    for view_depth, step in [(depth, 8), (depth, 8), (depth, 4), (depth[:, : WIDTH // 2], 4),
                             (depth[: HEIGHT // 2], 4), (depth, 8)]:
        kept = front_points(snapshot.camera, view_depth, step, grid)
        assert len(kept) > 0
        np.testing.assert_array_equal(kept, front_points(snapshot.camera, view_depth, step))
    assert not grid.subsample_ndc(HEIGHT, WIDTH, 8)[0].flags.writeable


def test_the_rays_counted_per_element_are_the_rays_the_effects_cast():
    """The cost model learns ms per ray from the effects' ray counters and each element's rays per
    pixel from the per-element counts: both must count the same rays (a reflection's hit shadow
    rays included), or the global residual absorbs the difference, which depends on what is
    selected (on arcade it sat near 3.5 and lagged for ~10 frames, putting early frames over
    budget).  Measured on one frame, the learned residual is then exactly 1."""
    from phrt.phrt_addon.select.cost_model import CostModel

    observed = []

    class Recording(CostModel):
        def observe(self, stats, result=None):
            observed.append(stats)
            super().observe(stats, result)

    renderer = FrameRenderer(threads=1)
    renderer.cost_model = Recording()
    result, gbuffer, _ = render(mirror_scene("RAYTRACE"), renderer)
    stats = observed[-1]
    element_rays = np.asarray(stats.element_rays)
    mirror_pixels = int(np.count_nonzero(gbuffer.opaque.element == 0))
    # The sun lights the mirror's hits: their shadow rays make the reflection cost more than a
    # ray per pixel, and they belong to the mirror.
    assert stats.effect_rays["reflections"] > mirror_pixels > 100
    assert element_rays[0] == pytest.approx(stats.effect_rays["reflections"])  # the mirror: reflections only
    assert stats.effect_rays["shadows"] > 0
    assert element_rays[1] == pytest.approx(stats.effect_rays["shadows"])  # the block: shadows only
    assert element_rays.sum() == pytest.approx(result.stats["rays"])
    assert renderer.cost_model.state()["measured_residual"] == pytest.approx(1.0, rel=1e-6)


def test_a_frame_without_traced_shadows_gathers_only_its_traced_elements_pixels(monkeypatch):
    """Reflections and refractions leave from their own element's pixels: without traced shadows
    the layers are gathered for the chosen elements only, and the frame is the same, pixel for
    pixel, as one gathered whole.  Traced shadows (a light, a selected caster) need every pixel."""
    snapshot = mirror_scene("RAYTRACE", lights=False)
    subset, gbuffer, _ = render(snapshot)
    assert subset.stats["reflection_rays"] > 0
    rays_from = FrameRenderer.ray_pixels(snapshot, np.array([True, True]), None)
    assert rays_from.tolist() == [True, False, False]  # the mirror; the block only casts shadows
    pixels = LayerPixels(gbuffer.opaque, gbuffer.origin, snapshot.camera, shading.MaterialTable(snapshot.materials),
                         rays_from)
    assert len(pixels) == np.count_nonzero(gbuffer.opaque.element == 0) > 0
    assert set(np.unique(pixels.element)) == {0}
    with_light = mirror_scene("RAYTRACE", lights=True)
    assert FrameRenderer.ray_pixels(with_light, np.array([True, True]), None) is None
    assert FrameRenderer.ray_pixels(with_light, np.array([True, False]), None).tolist() == [True, False, False]
    monkeypatch.setattr(FrameRenderer, "ray_pixels", staticmethod(lambda *args: None))
    whole, _, _ = render(mirror_scene("RAYTRACE", lights=False))
    assert whole.stats["reflection_rays"] == subset.stats["reflection_rays"]
    np.testing.assert_array_equal(whole.passes.combined, subset.passes.combined)


def test_a_frame_without_traced_shadows_reads_back_only_its_elements_rectangle(monkeypatch):
    """Without traced shadows the layers are read back in the rectangle the traced elements'
    bounds project to (the raster half clears the rest, as the GPU's read of a rectangle does):
    smaller than the frame, holding every pixel of the mirror, and the frame is the same, pixel for
    pixel, as one read whole."""
    rects = []
    read = ReferenceRaster.gbuffer
    monkeypatch.setattr(ReferenceRaster, "gbuffer", lambda self, rect=None: rects.append(rect) or read(self, rect))
    cropped, gbuffer, _ = render(mirror_scene("RAYTRACE", lights=False))
    x, y, w, h = rects[-1]
    assert 0 < w * h < 0.6 * WIDTH * HEIGHT
    rows, columns = np.nonzero(gbuffer.opaque.element == 0)
    assert len(rows) > 100
    assert rows.min() >= y and rows.max() < y + h and columns.min() >= x and columns.max() < x + w
    # Gathered inside the rectangle only: the same pixels, in the same order, as over the whole frame.
    snapshot = mirror_scene("RAYTRACE", lights=False)
    materials = shading.MaterialTable(snapshot.materials)
    mirror_only = np.array([True, False, False])
    inside = LayerPixels(gbuffer.opaque.cropped(rects[-1]), gbuffer.origin, snapshot.camera, materials, mirror_only,
                         rects[-1])
    whole_frame = LayerPixels(gbuffer.opaque, gbuffer.origin, snapshot.camera, materials, mirror_only)
    np.testing.assert_array_equal(inside.flat, whole_frame.flat)
    np.testing.assert_array_equal(inside.position, whole_frame.position)
    renderer = FrameRenderer(threads=1)
    renderer.crop_readback = False
    whole, _, _ = render(mirror_scene("RAYTRACE", lights=False), renderer)
    assert rects[-1] is None
    assert whole.stats["reflection_rays"] == cropped.stats["reflection_rays"] > 0
    np.testing.assert_array_equal(whole.passes.combined, cropped.passes.combined)


def test_screen_rect_holds_the_projection_of_every_point_of_its_boxes():
    from phrt.phrt_addon.raster.gbuffer import screen_rect
    view = camera((0.0, -8.0, 2.0), (0.0, 0.0, 0.5))
    rng = np.random.default_rng(3)
    for _ in range(50):
        centre = rng.uniform(-2.0, 2.0, size=3) + np.array([0.0, 0.0, 1.0])
        half = rng.uniform(0.02, 0.6, size=3)
        boxes = [(centre - half, centre + half)]
        rect = screen_rect(view, boxes, WIDTH, HEIGHT)
        points = rng.uniform(centre - half, centre + half, size=(400, 3))
        clip = np.c_[points, np.ones(len(points))] @ (view.projection @ view.view_matrix).T
        ndc = clip[:, :2] / clip[:, 3:4]
        columns = np.floor((ndc[:, 0] + 1) * 0.5 * WIDTH)
        rows = np.floor((ndc[:, 1] + 1) * 0.5 * HEIGHT)
        on_screen = (columns >= 0) & (columns < WIDTH) & (rows >= 0) & (rows < HEIGHT)
        if rect is None:  # only a rectangle too large to be worth it is refused here
            assert np.ptp(columns) * np.ptp(rows) > 0.3 * WIDTH * HEIGHT
            continue
        x, y, w, h = rect
        assert np.all((columns[on_screen] >= x) & (columns[on_screen] < x + w))
        assert np.all((rows[on_screen] >= y) & (rows[on_screen] < y + h))
    # A box reaching behind the camera projects without bound: read the frame whole.
    assert screen_rect(view, [(np.array([-1.0, -9.0, 1.0]), np.array([1.0, -7.0, 3.0]))], WIDTH, HEIGHT) is None
    assert screen_rect(view, [], WIDTH, HEIGHT) is None


def test_layer_pixels_gather_on_demand_what_the_whole_gather_gives():
    """``LayerPixels`` reads its images at the pixels asked for until a whole array is asked for:
    the same values either way, in either order, and nothing gathered whole by an indexed call."""
    snapshot = mirror_scene("RAYTRACE")
    _, gbuffer, _ = render(snapshot)
    materials = shading.MaterialTable(snapshot.materials)
    made = lambda: LayerPixels(gbuffer.opaque, gbuffer.origin, snapshot.camera, materials)  # noqa: E731
    whole = made()
    index = np.random.default_rng(3).choice(len(whole), 200, replace=False)
    parts = made()
    world, directions = parts.world(index), parts.view_directions(index)
    normals, distance = parts.normals(index), parts.camera_distance(index)
    assert not {"position", "normal", "world"} & set(parts._cache)  # nothing gathered whole yet
    np.testing.assert_array_equal(world, whole.world()[index])
    np.testing.assert_array_equal(directions, whole.view_directions()[index])
    np.testing.assert_array_equal(normals, whole.normals()[index])
    np.testing.assert_array_equal(distance, whole.camera_distance()[index])
    flat = whole.flat
    np.testing.assert_array_equal(whole.position, gbuffer.opaque.position.reshape(-1, 3)[flat])
    np.testing.assert_array_equal(whole.element, gbuffer.opaque.element.ravel()[flat])
    np.testing.assert_array_equal(whole.roughness, gbuffer.opaque.roughness.ravel()[flat])
    np.testing.assert_array_equal(whole.material, np.clip(gbuffer.opaque.material.ravel()[flat], 0,
                                                          len(materials.ior) - 1))
    # After the whole gather, an indexed call reads it (the same values).
    np.testing.assert_array_equal(whole.world(index), world)
    # Asked in parts for more than half the layer (shadow regions light after light), the whole
    # layer's world positions are made once and kept for the calls after.
    lights = made()
    halves = np.array_split(np.arange(len(lights)), 3)
    np.testing.assert_array_equal(lights.world(halves[0]), whole.world()[halves[0]])
    assert "world" not in lights._cache
    np.testing.assert_array_equal(lights.world(halves[1]), whole.world()[halves[1]])
    assert "world" in lights._cache
    np.testing.assert_array_equal(lights.world(halves[2]), whole.world()[halves[2]])


def test_id_passes_read_each_pixels_element_and_leave_out_ids_beyond_the_list():
    """The element, candidate and selected passes: 1-based element ids, 0 where no element or
    an id the element list does not have (a corrupt read-back, negative or beyond it)."""
    from types import SimpleNamespace
    from phrt.phrt_addon.frame import FrameRenderer
    front = np.array([[-1, 0, 1, 2], [3, 4, -7, 2**40]], np.int64)
    raster = SimpleNamespace(front_element=front, view_depth=np.array([[1.0, np.inf, 2.0, np.nan]] * 2, np.float32),
                             front_normal=np.zeros((2, 4, 3), np.float32))
    snapshot = SimpleNamespace(elements=[None] * 3)
    passes = FrameRenderer.frame_passes(snapshot, raster, None, np.array([False, True, True]),
                                   np.array([True, False, True]))
    np.testing.assert_array_equal(passes.element, [[0, 1, 2, 3], [0, 0, 0, 0]])
    np.testing.assert_array_equal(passes.candidate, [[0, 1, 0, 1], [0, 0, 0, 0]])
    np.testing.assert_array_equal(passes.selected, [[0, 0, 1, 1], [0, 0, 0, 0]])
    assert {passes.element.dtype, passes.candidate.dtype, passes.selected.dtype} == {np.dtype(np.float32)}
    assert np.isfinite(passes.depth).all()


def test_the_first_frames_selection_time_is_not_learned_as_the_stages():
    """The replay's first frame's select_ms holds one-time work (every mesh's bounds built, first
    calls): learned, it held the second frame's time left at 0 on atrium.  The select stage keeps
    its prior after the first frame and learns from the second."""
    from phrt.phrt_addon.select.cost_model import STAGE_PRIOR_MS
    snapshot = mirror_scene("HYBRID")
    renderer = FrameRenderer(threads=1)
    try:
        renderer.render(snapshot, ReferenceRaster(snapshot, ray_cast_gbuffer(snapshot)))
        assert renderer.cost_model.stage_ms()["select"] == pytest.approx(STAGE_PRIOR_MS["select"])
        second = renderer.render(snapshot, ReferenceRaster(snapshot, ray_cast_gbuffer(snapshot)))
        assert renderer.cost_model.stage_ms()["select"] != pytest.approx(STAGE_PRIOR_MS["select"])
        assert second.stats["select_ms"] > 0
    finally:
        renderer.close()
