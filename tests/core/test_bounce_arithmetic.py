"""The tracer's bounce levels done in few numpy calls give what the plainer numpy they replaced
gives: the component-by-component helpers against np.clip / max / power / nan_to_num, the hits'
shading attributes over several Embree sets against a hit-by-hit reference, the sets' frames made
again when the sets change, and every branch of a level (reflected, refracted, passing straight
on, or none of them traced further) without error and finite."""
import numpy as np
import pytest

from phrt.phrt_addon.scene import shading
from phrt.phrt_addon.scene.snapshot import Light, Material
from phrt.phrt_addon.trace import embree_scene, tracer
from phrt.phrt_addon.trace.embree_scene import TraceScene
from phrt.phrt_addon.trace.tracer import MAX_PASS_THROUGH

from test_tracer import GLASS, MIRROR, box, build, diffuse, quad, snapshot

SPECIALS = np.array([np.nan, np.inf, -np.inf, -0.0, 0.0, -1e-300, 1e-300, 0.5, 1.0, 1.5, -2.0, 1e6, 2e6])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_unit_clip_largest_and_finite_match_the_numpy_they_replace(dtype):
    rng = np.random.default_rng(0)
    values = np.r_[SPECIALS, rng.normal(0, 3, 200)].astype(dtype)
    np.testing.assert_array_equal(shading.unit_clip(values), np.clip(values, 0.0, 1.0))
    rows = rng.choice(values, (300, 3))
    np.testing.assert_array_equal(shading.largest(rows), rows.max(axis=-1))
    expected = np.clip(np.nan_to_num(values, nan=0.0, posinf=1e6, neginf=0.0), 0.0, 1e6)
    got = shading.finite(values)
    np.testing.assert_array_equal(got, expected)
    assert got.dtype == values.dtype


def test_pow5_is_the_fifth_power():
    x = np.r_[np.linspace(0.0, 1.0, 1001), 1e-80, 3.0]
    np.testing.assert_allclose(shading.pow5(x), x ** 5, rtol=1e-15, atol=0)
    single = np.linspace(0.0, 1.0, 1001, dtype=np.float32)
    assert shading.pow5(single).dtype == np.float32
    np.testing.assert_allclose(shading.pow5(single), single.astype(np.float64) ** 5, rtol=5e-7, atol=1e-30)


def test_specular_f0_is_float64_for_a_float32_gbuffer():
    """The reference raster passes float32 samples: F0 (and what is made from it) stays float64,
    the float32 dielectric term widened as before."""
    rng = np.random.default_rng(2)
    albedo, metallic = rng.random((50, 3)).astype(np.float32), rng.random(50).astype(np.float32)
    ior = rng.uniform(1.0, 2.5, 50).astype(np.float32)
    f0 = shading.specular_f0(albedo, metallic, ior)
    dielectric = shading.f0_dielectric(ior)[:, None] * np.ones((1, 3))
    assert f0.dtype == np.float64
    np.testing.assert_array_equal(f0, dielectric + (albedo - dielectric) * metallic[:, None])
    assert shading.specular_f90(f0).shape == (50, 1)


def test_hit_attributes_of_no_hits_without_any_set():
    """A scene with nothing to trace: misses only, empty attributes (no set to look up)."""
    scene = embree_scene.TraceScene(threads=1)
    try:
        scene.origin = np.zeros(3)
        hits = scene.intersect(np.zeros((3, 3)), np.tile([0.0, 0.0, 1.0], (3, 1)))
        index, material, element, normal, geometric, uv, set_index = scene.hit_surfaces(hits, np.isfinite(hits["t"]))
        assert len(index) == len(material) == len(element) == len(set_index) == 0
        assert normal.shape == geometric.shape == (0, 3) and uv.shape == (0, 2)
    finally:
        scene.close()


def _scene_of_several_sets(closing):
    """A floor and a box that cast shadows, a glass box that does not (two Embree sets), three
    materials, three elements, a textured uv layout."""
    materials = [diffuse("grey"), GLASS, diffuse("red", (0.8, 0.1, 0.1))]
    meshes = [quad("floor", (0, 0, 0), 10, 10, "+z", material=0, element=0),
              box("glass", (-1, -1, 0.5), (0.5, 0.5, 1.5), material=1, element=1),
              box("block", (1, 1, 0), (2, 2.5, 1), material=2, element=2)]
    snap = snapshot(meshes, materials)
    scene, radiance_tracer = build(snap)
    closing(scene)
    return snap, scene, radiance_tracer


def test_hit_attributes_over_several_sets_match_a_hit_by_hit_reference(closing):
    _, scene, _ = _scene_of_several_sets(closing)
    assert len(scene.sets()) == 2
    rng = np.random.default_rng(3)
    eye = scene.to_trace(np.tile([0.0, 0.0, 6.0], (400, 1)))
    target = scene.to_trace(np.c_[rng.uniform(-3, 3, 400), rng.uniform(-3, 3, 400), np.zeros(400)])
    hits = scene.intersect(eye, shading.normalize(target - eye))
    mask = np.isfinite(hits["t"])
    assert len(np.unique(hits["set"][mask])) == 2
    index, material, element, normal, geometric, uv, set_index = scene.hit_surfaces(hits, mask)
    np.testing.assert_array_equal(index, np.flatnonzero(mask))
    sets = hits["sets"]
    for k, i in enumerate(index):
        table = sets[hits["set"][i]].table()
        row = table.first[hits["geom"][i]] + hits["prim"][i]
        u, v = float(hits["u"][i]), float(hits["v"][i])
        weights = np.array([1.0 - u - v, u, v])
        want_normal = shading.normalize(weights @ table.corner_normals[row].astype(np.float64))
        want_geometric = shading.normalize(hits["Ng"][i].astype(np.float64))
        if want_geometric @ want_normal < 0:
            want_geometric = -want_geometric
        assert (material[k], element[k], set_index[k]) == (table.material[row], table.element[row], hits["set"][i])
        np.testing.assert_allclose(normal[k], want_normal, atol=1e-12)
        np.testing.assert_allclose(geometric[k], want_geometric, atol=1e-12)
        np.testing.assert_allclose(uv[k], weights @ table.corner_uvs[row].astype(np.float64), atol=1e-12)


def test_ray_offsets_follow_the_sets_when_they_are_rebuilt(closing):
    """The sets' frames are kept between calls: when the scene is replaced (another file: a floor
    and a millimetre box 5 km away, two precision clusters), the offsets are the new sets'."""
    _, scene, _ = _scene_of_several_sets(closing)
    scene.epsilon(scene.to_trace([[0.0, 0.0, 0.0]]), set_index=np.zeros(1, np.int64))  # first frames kept
    other = snapshot([quad("ground", (0, 0, 0), 10, 10, "+z", material=0),
                      box("speck", (5e3, 0, 0), (5e3 + 1e-3, 1e-3, 1e-3), material=1)], [diffuse("grey"), GLASS])
    scene.update(other)
    sets = scene.sets()
    assert len({tuple(s.offset) for s in sets}) == 2
    points = scene.to_trace([[0.0, 0.0, 0.0], [5e3, 0.0, 0.0]])
    for k, embree_set in enumerate(sets):
        expected = embree_scene.ray_epsilon(points - embree_set.offset, embree_set.extent, [2.0, 3.0])
        got = scene.epsilon(points, [2.0, 3.0], set_index=np.full(2, k, np.int64))
        np.testing.assert_array_equal(got, expected)


def _alpha_card_scene(closing, lights=(), floor=True):
    card = Material("card", base_color=(0.2, 0.6, 0.2), roughness=1.0, alpha=0.5)
    meshes = [quad("card", (0, 0, 1), 4, 4, "+z", material=0)]
    if floor:
        meshes.append(quad("floor", (0, 0, 0), 10, 10, "+z", material=1))
    snap = snapshot(meshes, [card, diffuse("red", (1.0, 0.1, 0.1))], lights, world=(0.3, 0.3, 0.3))
    scene, radiance_tracer = build(snap)
    closing(scene)
    return scene, radiance_tracer


def test_a_surface_passed_straight_through_too_often_shows_the_world_behind_it(closing):
    """A path out of pass-throughs traces nothing further (and nothing else of its level needs a
    secondary ray): behind the card is the world colour, as if there were no floor; with passes
    left, the floor shows."""
    scene, radiance_tracer = _alpha_card_scene(closing)
    alone_scene, alone = _alpha_card_scene(closing, floor=False)
    down = np.array([[0.0, 0.0, -1.0]])
    worn = radiance_tracer.radiance(scene.to_trace([[0.0, 0.0, 3.0]]), down, 1, passed=MAX_PASS_THROUGH)
    rays = radiance_tracer.rays
    assert rays == 1
    np.testing.assert_allclose(worn, alone.radiance(alone_scene.to_trace([[0.0, 0.0, 3.0]]), down, 1), rtol=1e-12)
    fresh = radiance_tracer.radiance(scene.to_trace([[0.0, 0.0, 3.0]]), down, 1)
    assert radiance_tracer.rays == rays + 2  # the card, then the floor behind it
    assert np.all(fresh[0, 1:] < worn[0, 1:] - 0.1)  # the red floor through the card, not the grey world


def _branches_scene(closing, shadowless_fill=True):
    card = Material("card", base_color=(0.2, 0.6, 0.2), roughness=1.0, alpha=0.5)
    materials = [diffuse("grey"), GLASS, MIRROR, card]
    meshes = [quad("floor", (0, 0, 0), 20, 20, "+z", material=0),
              box("glass", (-3, -1, 0.5), (-1, 1, 2.5), material=1),
              quad("mirror", (2, 0, 1.5), 2, 2, "-x", material=2),
              quad("card", (0, 3, 1), 2, 2, "+z", material=3)]
    lights = [Light("lamp", "POINT", (50.0, 50.0, 50.0), position=(0.0, 0.0, 5.0))]
    if shadowless_fill:
        lights.append(Light("fill", "POINT", (20.0, 20.0, 20.0), position=(0.0, -4.0, 4.0), cast_shadows=False))
    scene, radiance_tracer = build(snapshot(meshes, materials, lights, world=(0.1, 0.1, 0.1)))
    closing(scene)
    return scene, radiance_tracer


def test_every_branch_of_a_level_together_stays_finite_and_counts_its_rays(closing, monkeypatch):
    """One batch whose hits reflect (mirror), refract (glass, also with total internal reflection),
    pass straight on (an alpha card) and stop (matte), under a light that casts no shadow and one
    that does: finite values; each label's rays (all levels, shadow rays too) what its rays alone
    cost; the shadowless light adds no shadow ray."""
    scene, radiance_tracer = _branches_scene(closing)
    levels = []
    intersect = TraceScene.intersect
    monkeypatch.setattr(TraceScene, "intersect", lambda self, o, d: levels.append(len(o)) or intersect(self, o, d))
    rng = np.random.default_rng(5)
    eye = scene.to_trace(np.tile([0.0, 0.0, 8.0], (600, 1)))
    target = scene.to_trace(np.c_[rng.uniform(-4, 4, 600), rng.uniform(-4, 4, 600), np.zeros(600)])
    batch = rng.integers(0, 3, 600)
    radiance_tracer.batch_rays = np.zeros(3)
    color = radiance_tracer.radiance(eye, target - eye, 0, batch=batch)
    assert np.all(np.isfinite(color)) and np.all(color >= 0)
    assert len(levels) >= 4 and levels[0] == 600  # glass paths go several levels deep
    for label in range(3):
        _, alone = _branches_scene(closing)
        chosen = batch == label
        np.testing.assert_allclose(alone.radiance(eye[chosen], (target - eye)[chosen], 0), color[chosen], rtol=1e-12)
        assert radiance_tracer.batch_rays[label] == alone.rays + alone.shadow_rays
    _, lamp_only = _branches_scene(closing, shadowless_fill=False)
    lamp_only.radiance(eye, target - eye, 0)
    assert radiance_tracer.shadow_rays == lamp_only.shadow_rays > 0
    assert radiance_tracer.rays == lamp_only.rays


def test_leave_surface_keeps_directions_that_already_leave():
    directions = shading.normalize(np.array([[0.0, 1.0, 1.0], [0.0, 1.0, -1.0]]))
    normal = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    out = tracer.leave_surface(directions, normal)
    np.testing.assert_array_equal(out[0], directions[0])
    assert out[1] @ normal[1] >= tracer.MIN_LEAVING_COSINE * 0.999


def test_radiance_of_no_rays_and_of_bad_directions(closing):
    scene, radiance_tracer = _alpha_card_scene(closing, lights=[Light("sun", "SUN", (1.0, 1.0, 1.0),
                                                                      direction=(0.0, 0.0, -1.0))])
    assert radiance_tracer.radiance(np.zeros((0, 3)), np.zeros((0, 3)), 0).shape == (0, 3)
    origins = scene.to_trace(np.tile([0.0, 0.0, 3.0], (3, 1)))
    color = radiance_tracer.radiance(origins, np.array([[np.nan, 0, -1], [0, 0, 0], [0, 0, -np.inf]]), 0)
    assert np.all(np.isfinite(color)) and np.all(color >= 0)


def test_a_level_is_one_query_of_the_next(closing, monkeypatch):
    """One Embree query per level reached, and none for a level no ray reaches."""
    scene, radiance_tracer = _alpha_card_scene(closing)
    calls = []
    intersect = TraceScene.intersect

    def counted(self, origins, directions):
        calls.append(len(origins))
        return intersect(self, origins, directions)

    monkeypatch.setattr(TraceScene, "intersect", counted)
    radiance_tracer.radiance(scene.to_trace([[0.0, 0.0, 3.0], [0.1, 0.0, 3.0]]), np.array([[0.0, 0, -1]] * 2), 1)
    assert calls == [2, 2]  # the card, then the floor through it; the floor traces nothing further
