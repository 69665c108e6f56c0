"""GPU lighting against the numpy reference when the reference builds its own shadow maps.

The parity test of the GPU frame hands the GPU's own shadow maps (read back) to the numpy
reference, so a wrong shadow map drawn on the GPU would be wrong on both sides and pass.  Here
the reference makes its maps itself: for every view of every shadowed light (the views of
``shadowmap.light_views``), a ray per texel centre from the light through Embree against the
casting triangles of the snapshot gives the distance along the view axis of the first surface,
the quantity the GPU's shadow pass stores.  The two maps must agree texel for texel (but for
texels on a silhouette, where rasterisation and a ray through the centre may differ), and the
frame shaded by the GPU must match the reference shaded with its own maps."""
import os
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import math  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")
from embreex import rtcore_scene  # noqa: E402
from embreex.mesh_construction import TriangleMesh  # noqa: E402

from phrt.engine import extract  # noqa: E402
from phrt.engine.gpu.frame import GPUFrame  # noqa: E402
from phrt.phrt_addon.raster.reference_raster import ReferenceRaster  # noqa: E402
from phrt.phrt_addon.scene import rules  # noqa: E402
from phrt.phrt_addon.raster.shadowmap import ShadowMap, light_views  # noqa: E402
from phrt.sample_scenes import showcase  # noqa: E402

from gpu_probe import run_on_gpu  # noqa: E402

WIDTH, HEIGHT = 160, 120
pytestmark = pytest.mark.usefixtures("fresh_caches")


def lit_scene():
    """A sun, a point light (a cube of six views) and a spot over the showcase."""
    scene = showcase.build_showcase(WIDTH, HEIGHT)
    showcase.add_light("SPOT", (-2.0, -1.0, 3.0), 400.0, rotation=(math.radians(30), 0.0, math.radians(-60)),
                       name="Spot", spot_size=math.radians(60), spot_blend=0.3)
    showcase.add_light("POINT", (1.5, -2.0, 1.5), 150.0, color=(1.0, 0.6, 0.3), name="Bulb")
    scene.phrt.shadow_map_size = 256
    return scene


def casting_triangles(snapshot, origin):
    """(T, 3, 3) float32 triangles relative to ``origin`` of every material that casts shadows."""
    parts = []
    for mesh in snapshot.meshes:
        casts = np.array([rules.casts_shadow(material) for material in snapshot.materials])[mesh.tri_material]
        world = mesh.world_positions() - origin
        parts.append(world[mesh.triangles[casts]])
    return np.ascontiguousarray(np.concatenate(parts), dtype=np.float32)


def traced_map(view, triangles, clear):
    """The linear depth of the first casting surface at each texel centre (row 0 at the bottom)."""
    size = view.size
    centres = (np.arange(size) + 0.5) / size * 2.0 - 1.0
    x, y = np.meshgrid(centres, centres)  # row index = y from the bottom
    inverse = np.linalg.inv(view.view_proj_relative)
    axis = view.view[2, :3]

    def unproject(z):
        points = np.stack([x.ravel(), y.ravel(), np.full(x.size, z), np.ones(x.size)], axis=1) @ inverse.T
        return points[:, :3] / points[:, 3:4]

    if view.ortho:
        origins = unproject(-1.0)
        directions = np.broadcast_to(-axis, origins.shape).copy()
    else:
        origins = np.zeros((x.size, 3))
        far = unproject(1.0)
        directions = far / np.linalg.norm(far, axis=1, keepdims=True)
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, triangles)
    distances = np.full(x.size, 1e30, dtype=np.float32)
    hits = scene.run(origins.astype(np.float32), directions.astype(np.float32), dists=distances, query="DISTANCE")
    hits = np.asarray(hits, dtype=np.float64)
    hit = np.isfinite(hits) & (hits < 1e29)
    linear = np.full(x.size, clear, dtype=np.float64)
    points = origins[hit] + directions[hit] * hits[hit, None]
    linear[hit] = -(points @ axis)
    return linear


def own_shadow_maps(snapshot):
    """{light index: [ShadowMap]} built by ray casting, without the GPU."""
    maps = {}
    bounds = snapshot.bounds()
    size = int(snapshot.settings.shadow_map_size)
    for index, light in enumerate(snapshot.lights):
        if not light.cast_shadows:
            continue
        views = light_views(light, bounds, size)
        clear = float(max(view.far for view in views))
        triangles = casting_triangles(snapshot, views[0].origin)
        maps[index] = [ShadowMap.from_linear(view, traced_map(view, triangles, clear)) for view in views]
    return maps


def test_the_gpu_frame_matches_a_reference_that_builds_its_own_shadow_maps():
    scene = lit_scene()

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        frame = GPUFrame(snapshot)
        frame.draw()
        gbuffer = frame.gbuffer()
        opaque_albedo, transparent_albedo = frame.read_albedo()
        for layer, albedo in ((gbuffer.opaque, opaque_albedo), (gbuffer.transparent, transparent_albedo)):
            layer.albedo = np.ascontiguousarray(albedo[..., :3])
            layer.metallic = np.ascontiguousarray(albedo[..., 3])
        gpu_image = frame.shade(None)
        return snapshot, gbuffer, gpu_image, frame.read_shadow_maps()

    snapshot, gbuffer, gpu_image, gpu_maps = run_on_gpu(scene, job)
    own = own_shadow_maps(snapshot)
    assert sorted(own) == sorted(gpu_maps) and len(own) >= 3
    for index, maps in own.items():
        assert [m.view.size for m in maps] == [m.view.size for m in gpu_maps[index]]
        assert any((m.linear < m.view.far * 0.999).any() for m in maps)  # the light's views see casters
        for mine, theirs in zip(maps, gpu_maps[index]):
            relative = np.abs(mine.linear - theirs.linear) / np.maximum(np.abs(mine.linear), 1e-3)
            assert np.mean(relative > 1e-3) < 0.02, (index, np.mean(relative > 1e-3))

    reference = ReferenceRaster(snapshot, gbuffer, own).shade(None)
    covered = gbuffer.opaque.covered | gbuffer.transparent.covered
    luminance = reference[..., :3].mean(axis=2)
    lit = covered & (luminance > 0.02)
    assert lit.sum() > 0.3 * lit.size
    relative = np.abs(gpu_image[..., :3] - reference[..., :3]).max(axis=2) / np.maximum(luminance, 1e-3)
    assert np.mean(relative[lit] > 1e-2) < 0.01, np.mean(relative[lit] > 1e-2)
    assert np.median(relative[lit]) < 1e-4
    unshadowed = ReferenceRaster(snapshot, gbuffer, {}).shade(None)
    shadowed = lit & (np.abs(unshadowed[..., :3] - reference[..., :3]).max(axis=2) > 0.05 * luminance)
    assert shadowed.sum() > 0.02 * lit.sum()  # shadows are in view: the comparison covers them
