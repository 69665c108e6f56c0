"""The GPU-resident raster half (engine/gpu/: the frame, its passes and their resources).

- Parity: one G-buffer shaded by the GLSL passes and by the numpy reference
  (phrt_addon/raster/reference_raster.py, the equations of shading.py and shadowmap.py) agrees within
  1e-3 relative on lit pixels, with and without traced results.
- Lifetimes: a static replay creates no GPU resource after its first frame; a moved
  object re-uploads nothing, an edited mesh only itself, a moved light only its own
  shadow map; a file load and the end of a replay free what was created.
- Element ids are 32 bits: element 40,000 keeps its own pixels.
- RASTER reads back only the resolve targets, never the layers.
"""
import os
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import math  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")
import bmesh  # noqa: E402

from phrt.engine import extract, final, session  # noqa: E402
from phrt.engine.gpu import lighting, traced_textures  # noqa: E402
from phrt.engine.gpu.frame import GPUFrame  # noqa: E402
from phrt.engine.gpu.resources import gpu_module  # noqa: E402
from phrt.phrt_addon.frame_types import TracedTerms  # noqa: E402
from phrt.phrt_addon.raster import draw_chunks, reference_raster  # noqa: E402
from phrt.phrt_addon.scene.snapshot import Element, Material, MeshInstance  # noqa: E402
from phrt.sample_scenes import showcase  # noqa: E402

from gpu_probe import run_on_gpu  # noqa: E402

WIDTH, HEIGHT = 160, 120
SCENE_KINDS = ("mesh", "texture", "material_table", "shadow_map", "target")


# Registered once (conftest's ``blender``); every test starts with nothing cached.
pytestmark = pytest.mark.usefixtures("fresh_caches")


def lit_scene(extra_lights=0):
    """Every light kind (sun, point cube map, spot, area; five lights), metal, glass and an alpha card;
    ``extra_lights`` more point lights."""
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    showcase.add_light("SPOT", (-2.0, -1.0, 3.0), 400.0, rotation=(math.radians(30), 0.0, math.radians(-60)),
                       name="Spot", spot_size=math.radians(60), spot_blend=0.3)
    showcase.add_light("AREA", (0.0, 2.0, 3.0), 200.0, rotation=(math.radians(-20), 0.0, 0.0), name="Panel")
    showcase.add_light("POINT", (1.5, -2.0, 1.5), 150.0, color=(1.0, 0.6, 0.3), name="Bulb")
    for index in range(extra_lights):
        showcase.add_light("POINT", (-1.5 + 0.7 * index, 2.2, 1.2 + 0.3 * index), 80.0, color=(0.6, 0.7, 1.0),
                           name=f"Extra{index}")
    card = showcase.principled("Card", color=(0.2, 0.7, 0.3), alpha=0.5)
    showcase.mesh_object("Card", showcase.plane(1.0), card, location=(-0.8, -0.6, 0.6),
                         rotation=(math.radians(90), 0.0, 0.3))
    return scene


def gpu_and_reference(scene, traced_for=None):
    """(GPU combined, reference combined, lit mask) of the current frame."""
    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        frame = GPUFrame(snapshot)
        frame.draw()
        gbuffer = frame.gbuffer()
        opaque_albedo, transparent_albedo = frame.read_albedo()
        for layer, albedo in ((gbuffer.opaque, opaque_albedo), (gbuffer.transparent, transparent_albedo)):
            layer.albedo = np.ascontiguousarray(albedo[..., :3])
            layer.metallic = np.ascontiguousarray(albedo[..., 3])
        traced = traced_for(snapshot, gbuffer) if traced_for else None
        gpu_image = frame.shade(traced)
        reference = reference_raster.ReferenceRaster(snapshot, gbuffer, frame.read_shadow_maps()).shade(traced)
        return gpu_image, reference, gbuffer
    return run_on_gpu(scene, job)


def assert_parity(gpu_image, reference, gbuffer):
    covered = (gbuffer.opaque.covered | gbuffer.transparent.covered)
    luminance = reference[..., :3].mean(axis=2)
    lit = covered & (luminance > 0.02)
    assert lit.sum() > 0.3 * lit.size
    relative = np.abs(gpu_image[..., :3] - reference[..., :3]).max(axis=2) / np.maximum(luminance, 1e-3)
    # Shadow-map texels on the boundary between lit and shadowed flip with float32 rounding
    # differences between the GPU and numpy: a handful of pixels, never more.
    outliers = np.mean(relative[lit] > 1e-3)
    assert outliers < 0.002, f"{outliers:.2%} of lit pixels differ by more than 1e-3 relative"
    assert np.median(relative[lit]) < 1e-4


@pytest.mark.parametrize("extra_lights", [0, lighting.LIGHTS_PER_PASS - 4])
def test_glsl_lighting_matches_the_numpy_reference_on_one_gbuffer(extra_lights):
    """Five lights fit one lighting pass; with more than LIGHTS_PER_PASS, a second pass adds the rest."""
    scene = lit_scene(extra_lights)
    gpu_image, reference, gbuffer = gpu_and_reference(scene)
    assert gbuffer.transparent.covered.any()  # the glass and the card are in view
    assert_parity(gpu_image, reference, gbuffer)


def test_traced_visibility_reflection_and_refraction_reach_the_image_as_in_the_reference():
    scene = lit_scene()
    rng = np.random.default_rng(3)

    def traced_for(snapshot, gbuffer):
        traced = TracedTerms()
        opaque = np.flatnonzero(gbuffer.opaque.covered.ravel())
        chosen = rng.choice(opaque, size=len(opaque) // 3, replace=False)
        traced.shadow_visibility[("opaque", 0)] = (chosen, rng.integers(0, 2, len(chosen)).astype(np.float32))
        traced.shadow_visibility[("opaque", 3)] = (chosen[:100], np.zeros(100, np.float32))
        traced.shadow_visibility[("opaque", 4)] = (chosen[100:400], np.zeros(300, np.float32))  # second pass
        traced.reflection["opaque"] = (chosen[:500], np.tile([[2.0, 0.1, 0.1]], (500, 1)))
        transparent = np.flatnonzero(gbuffer.transparent.covered.ravel())
        traced.refraction = (transparent, np.tile([[0.0, 0.0, 3.0]], (len(transparent), 1)))
        return traced

    gpu_image, reference, gbuffer = gpu_and_reference(scene, traced_for)
    assert_parity(gpu_image, reference, gbuffer)
    # The refracted blue really shows through the glass.
    transparent = gbuffer.transparent.covered
    assert gpu_image[transparent][:, 2].mean() > 2.0 * gpu_image[transparent][:, 0].mean()


def render_frames(scene, frames, mode="RASTER"):
    """Render ``frames`` (a list of callables applied before each frame) in one replay session.
    Returns the creation counters before the first frame and after each, and each frame's stats."""
    scene.phrt.mode = mode
    counts = [dict(session.current().resources.created, upload=session.current().resources.uploads)]
    stats = []
    with final.ReplayState():
        for change in frames:
            change()
            bpy.ops.render.render()
            counts.append(dict(session.current().resources.created, upload=session.current().resources.uploads))
            stats.append(dict(session.last_frame().stats))
    return counts, stats


def created_between(counts, kind, first, last):
    return counts[last].get(kind, 0) - counts[first].get(kind, 0)


def test_static_replay_creates_nothing_after_its_first_frame_and_frees_everything_at_its_end():
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    before = session.current().resources.counts()
    counts, stats = render_frames(scene, [lambda: None] * 4, mode="HYBRID")
    for kind in ("shader", "upload", "mesh", "shadow_map", "target", "material_table"):
        assert created_between(counts, kind, 1, 4) == 0, kind
    assert created_between(counts, "mesh", 0, 1) > 0 and created_between(counts, "shadow_map", 0, 1) == 2
    # The recurring costs of the budget are the per-frame ones only: no set-up after frame 2.
    assert stats[0]["setup_ms"] > 0
    # Counted, not timed: no shader compiled, nothing uploaded (above), no Embree upload or rebuild.
    assert all(s["upload_ms"] == 0.0 for s in stats[1:])
    after = session.current().resources.counts()
    for kind in SCENE_KINDS:
        created = after.get(kind, (0, 0))[0] - before.get(kind, (0, 0))[0]
        freed = after.get(kind, (0, 0))[1] - before.get(kind, (0, 0))[1]
        assert created == freed, f"{kind}: {created} created, {freed} freed over the replay"


def test_moved_object_edited_mesh_and_moved_light_re_upload_only_what_changed():
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    cube = bpy.data.objects["RedCube"]
    lamp = bpy.data.objects["Lamp"]

    def move_cube():
        cube.location.x += 0.3

    def edit_cube():
        cube.data.vertices[0].co.z += 0.2
        cube.data.update()

    def move_lamp():
        lamp.location.y += 0.5

    counts, _ = render_frames(scene, [lambda: None, move_cube, edit_cube, move_lamp, lambda: None])
    # A moved object: its transform only (both lights see it: both maps are drawn again).
    assert created_between(counts, "mesh", 1, 2) == 0
    assert created_between(counts, "shadow_map", 1, 2) == 2
    # An edited mesh: that mesh only.
    assert created_between(counts, "mesh", 2, 3) == 1
    # A moved light: that light's map only.
    assert created_between(counts, "mesh", 3, 4) == 0
    assert created_between(counts, "shadow_map", 3, 4) == 1
    assert created_between(counts, "shadow_map", 4, 5) == 0


def test_f12_renders_keep_resources_and_a_file_load_frees_them(tmp_path):
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    scene.phrt.mode = "RASTER"
    bpy.ops.render.render()
    first = dict(session.current().resources.created, upload=session.current().resources.uploads)
    bpy.ops.render.render()
    assert session.current().resources.uploads == first["upload"]
    assert session.current().resources.created["shader"] == first["shader"]
    live = session.current().resources.live()
    assert live["mesh"] > 0 and live["shader"] > 0
    path = tmp_path / "saved.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    assert session.current().resources.empty
    assert all(count == 0 for count in session.current().resources.live().values())


def test_raster_mode_reads_back_no_layers_and_hybrid_does_when_candidates_are_visible():
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    _, raster_stats = render_frames(scene, [lambda: None] * 2, mode="RASTER")
    assert raster_stats[-1]["readback_ms"] == 0.0
    scene.phrt.use_budget_at = False
    scene.phrt.budget_ms = 1e5  # every candidate fits, however loaded the machine is
    _, hybrid_stats = render_frames(scene, [lambda: None] * 2, mode="HYBRID")
    assert hybrid_stats[-1]["readback_ms"] > 0.0


def test_element_ids_hold_32_bits():
    """Element 40,000 (beyond the former 15-bit field) keeps its pixels in the id target."""
    scene = showcase.empty_scene(64, 48)
    showcase.add_camera((0.0, -5.0, 0.0), (0.0, 0.0, 0.0))

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        index = 40_000
        snapshot.elements = [Element(name=f"E{i}", object_name="Quad") for i in range(index + 1)]
        snapshot.materials = [Material(name="Grey")]
        positions = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], np.float32)
        triangles = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
        normals = np.tile([[0.0, -1.0, 0.0]], (6, 1)).astype(np.float32)
        snapshot.meshes = [MeshInstance("Quad", np.eye(4), positions, triangles, normals, None,
                                        np.zeros(2, np.int32), np.full(2, index, np.int32))]
        frame = GPUFrame(snapshot)
        frame.draw()
        return frame.front_element

    front = run_on_gpu(scene, job)
    assert front[24, 32] == 40_000
    assert front[0, 0] == -1


def test_the_first_draw_of_a_lighting_configuration_is_counted_as_set_up():
    """llvmpipe (like any driver) compiles a pipeline state on its first draw: the frame that
    first shades with a configuration books that time as one-time work, the next frames do not."""
    scene = lit_scene()

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        setups = []
        for measure in (False, False, True, True):
            frame = GPUFrame(snapshot)
            frame.draw()
            frame.shade(None, measure_change=measure)
            setups.append(frame.stats["shade_setup_ms"])
        return setups

    setups = run_on_gpu(scene, job)
    assert setups[0] > 0 and setups[1] == 0.0
    assert setups[2] > 0 and setups[3] == 0.0  # measuring the traced change draws other targets


def test_the_lighting_pass_that_also_composites_equals_the_separate_composite():
    """With all lights in one pass, that pass composites the opaque layer too: the image and the
    measured traced change (the error-aware relevance) equal the separate composite's."""
    scene = lit_scene()

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        results = []
        for fused in (True, False):
            frame = GPUFrame(snapshot)
            frame.draw()
            assert frame.fused  # five lights: one pass, with the sampler it needs
            frame.fused = fused
            gbuffer = frame.gbuffer()
            traced = TracedTerms()
            opaque = np.flatnonzero(gbuffer.opaque.covered.ravel())
            chosen = np.random.default_rng(5).choice(opaque, size=len(opaque) // 4, replace=False)
            traced.shadow_visibility[("opaque", 1)] = (chosen, np.zeros(len(chosen), np.float32))
            traced.reflection["opaque"] = (chosen[:800], np.tile([[0.1, 1.5, 0.1]], (800, 1)))
            transparent = np.flatnonzero(gbuffer.transparent.covered.ravel())
            traced.refraction = (transparent, np.tile([[0.0, 0.0, 3.0]], (len(transparent), 1)))
            image = frame.shade(traced, measure_change=True)
            results.append((image, frame.traced_change()))
        return results

    (fused_image, fused_change), (image, change) = run_on_gpu(scene, job)
    assert np.abs(fused_change[..., 0]).max() > 0.1 and np.abs(fused_change[..., 1]).max() > 0.1
    np.testing.assert_allclose(fused_image, image, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(fused_change, change, rtol=1e-5, atol=1e-6)


def test_the_lighting_pass_composites_only_when_the_gl_has_the_samplers_for_it():
    """All lights in one pass composite the opaque layer there only if the implementation offers
    the samplers (4 + 2 per light + 1): a GL with fewer composites in its own pass, to the same image."""
    scene = lit_scene()  # five lights: 15 samplers when composited in the lighting pass

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        resources = session.current().resources
        found = resources.max_fragment_samplers()
        images = []
        for available in (15, 14):
            resources._max_fragment_samplers = available
            frame = GPUFrame(snapshot)
            frame.draw()
            images.append((frame.fused, frame.shade(None)))
        resources._max_fragment_samplers = found
        return found, images

    found, ((fused, image), (separate, separate_image)) = run_on_gpu(scene, job)
    assert found >= 16  # every GL offers 16
    assert fused and not separate
    np.testing.assert_allclose(image, separate_image, rtol=1e-5, atol=1e-6)


def test_what_stands_for_untraced_terms_has_the_traced_textures_size_and_format():
    """A driver compiles a shader variant per sampled texture format and size class (llvmpipe
    JITs one in 0.3-0.7 s): the textures bound where nothing was traced must look like the
    traced ones to the sampler, or every change of what is traced mid-replay compiles anew.
    They read as "keep the shadow map" (-1) and "no traced radiance" (alpha 0)."""
    scene = lit_scene()

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        frame = GPUFrame(snapshot)
        frame.draw()
        gbuffer = frame.gbuffer()
        traced = TracedTerms()
        opaque = np.flatnonzero(gbuffer.opaque.covered.ravel())[:50]
        traced.shadow_visibility[("opaque", 0)] = (opaque, np.zeros(len(opaque), np.float32))
        traced.reflection["opaque"] = (opaque, np.ones((len(opaque), 3)))
        uploads = traced_textures.upload(gpu_module(), frame.resources, traced, frame.width, frame.height)
        describe = lambda texture: (texture.format, texture.width, texture.height)  # noqa: E731
        standins = {name: frame.targets[name] for name in ("no_visibility", "no_radiance")}
        return ({name: describe(texture) for name, texture in standins.items()},
                describe(uploads["visibility"][("opaque", 0)]), describe(uploads["reflection"]["opaque"]),
                {name: np.asarray(texture.read().to_list(), np.float32) for name, texture in standins.items()})

    standins, visibility, reflection, values = run_on_gpu(scene, job)
    assert standins["no_visibility"] == visibility == ("R32F", WIDTH, HEIGHT)
    assert standins["no_radiance"] == reflection == ("RGBA32F", WIDTH, HEIGHT)
    assert np.all(values["no_visibility"] == -1.0)
    assert np.all(values["no_radiance"] == 0.0)


def test_chunks_outside_the_view_are_not_drawn_and_the_frame_is_the_same():
    """Culling changes what is drawn, never what is seen: a floor of many chunks that reaches
    far outside the view and objects behind the camera give the same G-buffer and image as
    drawing everything; vertices shared between corners give the corners' own attributes."""
    scene = lit_scene()
    tiles = showcase.principled("Tiles", color=(0.3, 0.5, 0.7), roughness=0.4)
    showcase.mesh_object("BigFloor", lambda bm: bmesh.ops.create_grid(bm, x_segments=120, y_segments=120, size=30.0),
                         tiles, location=(0.0, 0.0, -0.01))
    showcase.mesh_object("Behind", showcase.sphere(1.0), tiles, location=(9.0, -11.0, 4.0), smooth=True)

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        results = []
        for cull in (True, False):
            original = draw_chunks.boxes_outside
            if not cull:
                draw_chunks.boxes_outside = lambda matrix, boxes: np.zeros(len(boxes), bool)
            try:
                frame = GPUFrame(snapshot)
                frame.draw()
                gbuffer = frame.gbuffer()
                image = frame.shade(None)
            finally:
                draw_chunks.boxes_outside = original
            results.append((dict(frame.stats), gbuffer, image))
        return results

    (culled_stats, culled, culled_image), (all_stats, everything, all_image) = run_on_gpu(scene, job)
    assert all_stats["chunks_culled"] == 0
    assert culled_stats["chunks_culled"] >= 3  # chunks of the big floor and the sphere behind
    assert culled_stats["chunks_drawn"] + culled_stats["chunks_culled"] == all_stats["chunks_drawn"]
    for name in ("position", "normal", "element", "material"):
        assert np.array_equal(getattr(culled.opaque, name), getattr(everything.opaque, name), equal_nan=True), name
    assert np.array_equal(culled_image, all_image)
    assert culled.opaque.covered.mean() > 0.6  # the big floor fills the view's lower part


def test_numpys_blas_runs_one_thread_while_phrt_renders_and_gets_its_threads_back():
    """OpenBLAS's idle threads spin on the cores the GPU driver renders with: a frame (F12 or a
    replay's) runs with one BLAS thread; Blender's other users of numpy get theirs back after."""
    blas = session.current().blas
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    before = blas.thread_counts()
    seen = []
    with final.ReplayState(on_frame=lambda result, snapshot: seen.append(blas.thread_counts())):
        bpy.ops.render.render()
        bpy.ops.render.render()
        assert blas.thread_counts() == [1] * len(before)  # between a replay's frames too
    assert seen == [[1] * len(before)] * 2
    assert blas.thread_counts() == before
    # An F12 render outside any replay: the engine's render() holds the limit itself.
    write = final.FinalRender._write
    final.FinalRender._write = lambda self, *args: (seen.append(blas.thread_counts()), write(self, *args))
    try:
        bpy.ops.render.render()
    finally:
        final.FinalRender._write = write
    assert seen[-1] == [1] * len(before) and len(seen) == 3
    assert blas.thread_counts() == before


def test_each_lighting_pass_compiles_in_its_lights_kinds_and_shadow_maps():
    """A lighting variant computes only the kind and the shadow lookup of each light it holds
    (llvmpipe runs both sides of every select): sun one view, point and area cube maps, spot
    one view, a light without shadows no lookup at all."""
    scene = lit_scene()
    bpy.data.objects["Bulb"].data.use_shadow = False

    def job(engine, depsgraph):
        frame = GPUFrame(extract.extract(depsgraph))
        frame.draw()
        kinds = {light.name: light.kind for light in frame.snapshot.lights}
        return frame.lighting_names, [light.name for light in frame.snapshot.lights], kinds

    names, order, kinds = run_on_gpu(scene, job)
    expected = {"Sun": "sv", "Lamp": "pc", "Spot": "tv", "Panel": "ac", "Bulb": "pn"}
    letters = "".join(expected[name] for name in order)
    assert names == [f"lighting5_{letters}", f"lighting5_composite_{letters}"]


def test_a_light_without_shadows_lights_as_the_reference_does():
    scene = lit_scene()
    bpy.data.objects["Bulb"].data.use_shadow = False
    bpy.data.objects["Spot"].data.use_shadow = False
    gpu_image, reference, gbuffer = gpu_and_reference(scene)
    assert_parity(gpu_image, reference, gbuffer)


def test_a_rectangle_of_the_layers_reads_back_as_the_same_pixels_of_the_whole():
    """``GPUFrame.gbuffer(rect)`` (a frame tracing reflections and refractions only): inside the
    rectangle every layer's pixels equal the whole read-back's, outside they read as cleared
    ones; the core's ``GBufferLayer.cropped`` (the reference raster's) is the same thing."""
    scene = lit_scene()
    rect = (23, 17, 61, 40)  # x, y, w, h: row 0 at the bottom, off the frame's edges

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        whole_frame = GPUFrame(snapshot)
        whole_frame.draw()
        whole = whole_frame.gbuffer()
        part_frame = GPUFrame(snapshot)
        part_frame.draw()
        return whole, part_frame.gbuffer(rect), part_frame.gbuffer(rect) is part_frame.gbuffer(rect)

    whole, part, kept = run_on_gpu(scene, job)
    assert kept  # the same rectangle again: the kept read-back
    x, y, w, h = rect
    inside = np.zeros((HEIGHT, WIDTH), bool)
    inside[y:y + h, x:x + w] = True
    for name in ("opaque", "transparent"):
        full, cut = getattr(whole, name), getattr(part, name)
        expected = full.cropped(rect)
        assert full.covered[inside].sum() > (0.5 * inside.sum() if name == "opaque" else 10)  # it holds surfaces
        assert full.covered[~inside].any()  # and there are some outside it to leave out
        assert not cut.covered[~inside].any() and (cut.element[~inside] == -1).all()
        assert full.geometric_normal is not None  # the showcase's frames may trace: face normals too
        for field in ("covered", "position", "normal", "roughness", "material", "element", "geometric_normal"):
            np.testing.assert_array_equal(getattr(cut, field), getattr(expected, field), err_msg=f"{name}.{field}")


def test_the_gbuffers_face_normals_are_the_triangles_that_embree_hits():
    """A frame that may trace writes each pixel's face normal (``GBUFFER_FRAG``'s screen
    derivatives of the position, 8 bits an axis): camera rays through the covered pixels of both
    layers hit, in Embree, triangles whose normal is within 2 degrees of it (the numpy
    reconstruction from neighbouring positions is off by more wherever it straddles an edge of a
    curved surface); a RASTER frame writes none."""
    from phrt.phrt_addon.trace.embree_scene import TraceScene
    scene = lit_scene()

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        frames = {}
        for mode in ("HYBRID", "RASTER"):
            snapshot.settings.mode = mode
            frame = GPUFrame(snapshot)
            frame.draw()
            frames[mode] = (frame.faces, frame.gbuffer())
        return snapshot, frames

    snapshot, frames = run_on_gpu(scene, job)
    faces, gbuffer = frames["HYBRID"]
    assert faces and not frames["RASTER"][0]
    assert frames["RASTER"][1].opaque.geometric_normal is None
    trace_scene = TraceScene(threads=1)
    try:
        trace_scene.update(snapshot)
        for name in ("opaque", "transparent"):
            layer = getattr(gbuffer, name)
            assert layer.geometric_normal.dtype == np.uint8 and layer.geometric_normal.shape == (HEIGHT, WIDTH, 4)
            # Opaque pixels behind the transparent layer: the camera ray hits the glass first.
            seen = layer.covered if name == "transparent" else layer.covered & ~gbuffer.transparent.covered
            flat = np.flatnonzero(seen.ravel())
            assert len(flat) > (5000 if name == "opaque" else 100)
            position = layer.position.reshape(-1, 3)[flat].astype(np.float64)
            distance = np.linalg.norm(position, axis=1)
            origins = np.broadcast_to(trace_scene.to_trace(np.asarray(snapshot.camera.position)[None, :]),
                                      position.shape).copy()
            hits = trace_scene.intersect(origins, position / distance[:, None])
            at_depth = np.abs(hits["t"] - distance) < 1e-3 * distance
            assert at_depth.mean() > 0.98
            embree = hits["Ng"].astype(np.float64)[at_depth]
            embree /= np.linalg.norm(embree, axis=1, keepdims=True)
            stored = layer.geometric_normal.reshape(-1, 4)[flat][at_depth]
            assert np.all(stored[:, 3] == 255)
            decoded = stored[:, :3] / 127.5 - 1.0
            decoded /= np.linalg.norm(decoded, axis=1, keepdims=True)
            cosine = np.abs(np.sum(decoded * embree, axis=1))
            assert np.mean(cosine > np.cos(np.radians(2.0))) > 0.99, name
    finally:
        trace_scene.close()
