"""The pixels a caster can shadow: both indexes must give the brute-force answer."""
import numpy as np
import pytest

from phrt.phrt_addon.trace.element_bounds import ElementBounds
from phrt.phrt_addon.trace.shadow_region import (PointChunks, ShadowRegionIndex, TiledShadowRegions,
                                               shadow_region)
from phrt.phrt_addon.scene.snapshot import Light

LIGHTS = {
    "sun": Light("Sun", "SUN", (3.0, 3.0, 3.0), direction=(-0.4, 0.5, -0.77)),
    "point": Light("Lamp", "POINT", (100.0, 100.0, 100.0), position=(1.0, -2.0, 4.0)),
    "spot": Light("Spot", "SPOT", (100.0, 100.0, 100.0), position=(-3.0, 1.0, 5.0), direction=(0.3, 0.0, -1.0)),
}


def random_casters(rng, count, largest_half, lift):
    """``count`` caster bounds: centres spread over the scene (z squeezed, lifted by ``lift``),
    half sizes from 0.05 to ``largest_half``."""
    bounds = []
    for _ in range(count):
        centre = rng.uniform(-6, 6, size=3) * np.array([1.0, 1.0, 0.3]) + np.array([0, 0, lift])
        half = rng.uniform(0.05, largest_half, size=3)
        bounds.append((centre - half, centre + half))
    return bounds


@pytest.mark.parametrize("kind", sorted(LIGHTS))
def test_index_matches_brute_force_for_many_casters(kind):
    rng = np.random.default_rng(7)
    points = rng.uniform(-10, 10, size=(20000, 3)) * np.array([1.0, 1.0, 0.2])
    light = LIGHTS[kind]
    index = ShadowRegionIndex(light, points)
    hits = 0
    for _ in range(40):  # the first queries test every point, the later ones a sorted window
        centre = rng.uniform(-6, 6, size=3) * np.array([1.0, 1.0, 0.3]) + np.array([0, 0, 1.0])
        half = rng.uniform(0.05, 1.5, size=3)
        bounds = (centre - half, centre + half)
        expected = shadow_region(light, bounds, points)
        got = index.region(bounds)
        # float32 light-space coordinates: only points within rounding of the boundary may differ
        assert np.count_nonzero(got != expected) <= 2
        hits += expected.sum()
    assert hits > 1000  # the casters do shadow something: the comparison is not vacuous


def test_light_inside_the_caster_bounds_reaches_every_point():
    points = np.random.default_rng(1).uniform(-5, 5, size=(500, 3))
    light = LIGHTS["point"]
    bounds = (np.array(light.position) - 1.0, np.array(light.position) + 1.0)
    assert ShadowRegionIndex(light, points).region(bounds).all()


def pixel_like_points(offset=0.0, nan_every=0):
    """A ground plane and a back wall seen row by row, as a G-buffer's pixels are ordered, and
    each point's 8x8 screen tile."""
    u, v = np.meshgrid(np.linspace(-10, 10, 160), np.linspace(-10, 10, 120))
    ground = np.stack([u.ravel(), v.ravel(), np.zeros(u.size)], axis=1)
    wall = np.stack([u.ravel(), np.full(u.size, 10.0), v.ravel() + 10.0], axis=1)
    points = np.concatenate([ground, wall]) + offset
    if nan_every:
        points[::nan_every] = np.nan
    rows, cols = np.divmod(np.arange(u.size), 160)
    tiles = (rows // 8) * 20 + cols // 8
    return points, np.r_[tiles, tiles + 1000]


@pytest.mark.parametrize("kind", sorted(LIGHTS))
@pytest.mark.parametrize("offset, nan_every", [(0.0, 0), (0.0, 7), (1e5, 0)])
@pytest.mark.parametrize("grouping", ["runs", "tiles"])
def test_groups_of_pixels_are_culled_and_the_answer_stays_exact(kind, offset, nan_every, grouping):
    """Coherent points (pixels, in runs along a row or in screen tiles) let a caster skip the
    groups its cylinder or cone misses, with the brute-force answer: also with holes (NaN: no
    surface) and far from the origin."""
    rng = np.random.default_rng(11)
    points, tiles = pixel_like_points(offset, nan_every)
    light = LIGHTS[kind]
    if light.kind != "SUN":
        light = Light(light.name, light.kind, light.color, position=np.asarray(light.position) + offset,
                      direction=light.direction)
    index = TiledShadowRegions(light, points, PointChunks(points, keys=tiles if grouping == "tiles" else None))
    hits = 0
    for _ in range(30):
        centre = rng.uniform(-6, 6, size=3) * np.array([1.0, 1.0, 0.3]) + np.array([0, 0, 1.5]) + offset
        half = rng.uniform(0.05, 0.5, size=3)
        bounds = (centre - half, centre + half)
        with np.errstate(invalid="ignore"):
            expected = shadow_region(light, bounds, points)
        np.testing.assert_array_equal(index.region(bounds), expected)
        hits += expected.sum()
    assert hits > 500
    # Most points were never looked at: the culling is real.
    assert index.points_tested < (0.5 if grouping == "runs" else 0.25) * index.queries * len(points)


def test_a_tiled_index_over_few_points_and_no_points():
    light = LIGHTS["point"]
    bounds = (np.array([0.0, 0.0, 0.5]), np.array([0.5, 0.5, 1.0]))
    assert TiledShadowRegions(light, np.zeros((0, 3))).region(bounds).shape == (0,)
    points = np.array([[0.2, 0.2, 0.0], [np.inf, 0.0, 0.0], [5.0, 5.0, 0.0]])
    with np.errstate(invalid="ignore"):  # the infinite point
        expected = shadow_region(light, bounds, points)
    np.testing.assert_array_equal(TiledShadowRegions(light, points, PointChunks(points, size=2)).region(bounds),
                                  expected)


@pytest.mark.parametrize("kind", sorted(LIGHTS))
def test_counts_of_all_casters_at_once_match_each_region(kind):
    """The frame's footprints: every caster's region counted in one call, the same counts as one
    region at a time (blocks of casters small enough to take several)."""
    rng = np.random.default_rng(11)
    points = rng.uniform(-10, 10, size=(3000, 3)) * np.array([1.0, 1.0, 0.2])
    light = LIGHTS[kind]
    bounds = random_casters(rng, 25, 1.5, 1.0)
    if kind != "sun":  # a caster around the light: every point
        bounds.append((np.array(light.position) - 1.0, np.array(light.position) + 1.0))
    one_by_one = np.array([np.count_nonzero(ShadowRegionIndex(light, points)._test(
        ShadowRegionIndex(light, points).coords, b)) for b in bounds])
    counts = ShadowRegionIndex(light, points).counts(bounds, chunk=4 * len(points))
    # float32 light-space coordinates: a point within rounding of a cone's boundary may differ
    assert np.abs(counts - one_by_one).max() <= 1
    assert np.count_nonzero(counts != one_by_one) <= 2
    assert one_by_one.sum() > 500  # the casters do shadow something
    assert ShadowRegionIndex(light, points[:0]).counts(bounds).tolist() == [0] * len(bounds)
    assert ShadowRegionIndex(light, points).counts([]).shape == (0,)


def test_element_bounds_follow_a_moved_mesh_and_match_its_world_vertices():
    """World bounds are kept per (geometry, matrix): the same frame again gives the same boxes,
    a mesh moved by its matrix gets new ones, and each box holds exactly its element's
    vertices' world extent (up to rotation: the box of the local box's corners)."""
    from types import SimpleNamespace

    from phrt.phrt_addon.scene.snapshot import MeshInstance
    rng = np.random.default_rng(5)
    positions = rng.uniform(-1, 1, size=(30, 3)).astype(np.float32)
    triangles = np.arange(30, dtype=np.int32).reshape(10, 3)
    tri_element = np.array([0] * 5 + [2] * 5, np.int32)
    mesh = MeshInstance("m", np.eye(4), positions, triangles, np.zeros((30, 3), np.float32), None,
                        np.zeros(10, np.int32), tri_element)
    snapshot = SimpleNamespace(meshes=[mesh], elements=[None] * 3)
    bounds = ElementBounds()
    first = bounds(snapshot)
    assert first[1] is None
    for element in (0, 2):
        vertices = positions[triangles[tri_element == element]].reshape(-1, 3)
        np.testing.assert_allclose(first[element][0], vertices.min(axis=0), rtol=0, atol=1e-6)
        np.testing.assert_allclose(first[element][1], vertices.max(axis=0), rtol=0, atol=1e-6)
    again = bounds(snapshot)
    assert all(np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]) for a, b in zip(first[::2], again[::2]))
    moved = np.eye(4)
    moved[:3, 3] = (10.0, -2.0, 0.5)
    mesh.matrix_world = moved
    shifted = bounds(snapshot)
    np.testing.assert_allclose(shifted[0][0], first[0][0] + moved[:3, 3], rtol=0, atol=1e-9)
    np.testing.assert_allclose(shifted[2][1], first[2][1] + moved[:3, 3], rtol=0, atol=1e-9)
    with pytest.raises(ValueError):  # the kept boxes are shared between frames: read-only
        shifted[0][0][0] = 0.0


def _reference_region(light, bounds, points):
    """The rule of ``shadow_region`` written with (n, 3) products, as it was first written."""
    low, high = bounds
    centre, radius = (low + high) / 2.0, 0.5 * float(np.linalg.norm(high - low)) + 1e-6
    if light.kind == "SUN":
        direction = np.asarray(light.direction, float) / np.linalg.norm(light.direction)
        relative = points - centre
        along = relative @ direction
        lateral = relative - along[:, None] * direction
        return (along > -radius) & (np.einsum("ij,ij->i", lateral, lateral) <= radius * radius)
    to_centre = centre - np.asarray(light.position, float)
    distance = float(np.linalg.norm(to_centre))
    if distance <= radius:
        return np.ones(len(points), bool)
    to_point = points - np.asarray(light.position, float)
    point_distance = np.linalg.norm(to_point, axis=1)
    cos_point = (to_point @ (to_centre / distance)) / np.maximum(point_distance, 1e-30)
    return (cos_point >= np.sqrt(max(1.0 - (radius / distance) ** 2, 0.0))) & (point_distance > distance - radius)


@pytest.mark.parametrize("kind", sorted(LIGHTS))
def test_the_column_arithmetic_gives_the_rule_and_all_casters_at_once_give_each_region(kind):
    """``shadow_region`` (by columns) against the rule with (n, 3) products (rounding may move
    a point on the boundary, no more); ``regions`` of many casters, one with the light inside
    its bounds, against ``region`` of each."""
    rng = np.random.default_rng(5)
    points, tiles = pixel_like_points()
    light = LIGHTS[kind]
    bounds_list = random_casters(rng, 12, 2.0, 1.5)
    if light.kind != "SUN":
        bounds_list.insert(3, (np.asarray(light.position) - 0.5, np.asarray(light.position) + 0.5))
    hits = 0
    for bounds in bounds_list:
        got = shadow_region(light, bounds, points)
        assert np.count_nonzero(got != _reference_region(light, bounds, points)) <= 2
        hits += got.sum()
    assert hits > 1000
    index = TiledShadowRegions(light, points, PointChunks(points, keys=tiles))
    together = index.regions(bounds_list)
    assert index.queries == len(bounds_list)
    for bounds, region in zip(bounds_list, together):
        np.testing.assert_array_equal(region, shadow_region(light, bounds, points))
        np.testing.assert_array_equal(region, TiledShadowRegions(light, points, PointChunks(points, keys=tiles))
                                      .region(bounds))
    if light.kind != "SUN":
        assert together[3].all()
    assert index.regions([]) == []
