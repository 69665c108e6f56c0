"""The pixels a caster can shadow: both indexes must give the brute-force answer."""
import numpy as np
import pytest

from phrt.phrt_addon.trace.shadow_region import PointChunks, ShadowRegionIndex, TiledShadowRegions, shadow_region
from phrt.phrt_addon.scene.snapshot import Light

LIGHTS = {
    "sun": Light("Sun", "SUN", (3.0, 3.0, 3.0), direction=(-0.4, 0.5, -0.77)),
    "point": Light("Lamp", "POINT", (100.0, 100.0, 100.0), position=(1.0, -2.0, 4.0)),
    "spot": Light("Spot", "SPOT", (100.0, 100.0, 100.0), position=(-3.0, 1.0, 5.0), direction=(0.3, 0.0, -1.0)),
}


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
