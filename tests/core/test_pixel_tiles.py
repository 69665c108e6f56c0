"""Screen tiles straight from a G-buffer image: the same shadow regions as the brute force, and
as tiles of sorted points (PointChunks), with the culling still real."""
import numpy as np
import pytest

from phrt.phrt_addon.scene.snapshot import Light
from phrt.phrt_addon.trace.pixel_tiles import ImageTiles
from phrt.phrt_addon.trace.shadow_region import PointChunks, TiledShadowRegions, shadow_region

LIGHTS = {
    "sun": Light("Sun", "SUN", (3.0, 3.0, 3.0), direction=(-0.4, 0.5, -0.77)),
    "point": Light("Lamp", "POINT", (100.0, 100.0, 100.0), position=(1.0, -2.0, 4.0)),
    "spot": Light("Spot", "SPOT", (100.0, 100.0, 100.0), position=(-3.0, 1.0, 5.0), direction=(0.3, 0.0, -1.0)),
}


def layer_image(height=75, width=101, origin=(0.0, 0.0, 0.0), holes=0.1, nan_pixels=0):
    """A float32 position image relative to ``origin`` (a ground plane below a back wall, as a
    camera sees them: sizes not multiples of the tile), with uncovered pixels and NaN ones; and
    the flat indices of the covered pixels."""
    rng = np.random.default_rng(5)
    v, u = np.meshgrid(np.linspace(-10, 10, height), np.linspace(-10, 10, width), indexing="ij")
    wall = v > 3.0
    position = np.stack([u, np.where(wall, 10.0, v * 3.0), np.where(wall, (v - 3.0) * 2.0, 0.0)], axis=2)
    position = position.astype(np.float32)
    covered = rng.random((height, width)) > holes
    flat = np.flatnonzero(covered)
    if nan_pixels:
        position.reshape(-1, 3)[rng.choice(flat, nan_pixels, replace=False)] = np.nan
    return position, flat, np.asarray(origin, np.float64)


def world(position, flat, origin):
    return position.reshape(-1, 3)[flat].astype(np.float64) + origin


@pytest.mark.parametrize("kind", sorted(LIGHTS))
@pytest.mark.parametrize("origin, nan_pixels, holes", [((0.0, 0.0, 0.0), 0, 0.1), ((0.0, 0.0, 0.0), 40, 0.1),
                                                      ((1e5, -3e4, 7.0), 0, 0.1), ((0.0, 0.0, 0.0), 10, 0.7)])
def test_regions_over_image_tiles_are_exact_and_culled(kind, origin, nan_pixels, holes):
    """Dense layers (the image copied) and sparse ones (a transparent layer: its points scattered)."""
    position, flat, origin = layer_image(origin=origin, nan_pixels=nan_pixels, holes=holes)
    points = world(position, flat, origin)
    light = LIGHTS[kind]
    if light.kind != "SUN":
        light = Light(light.name, light.kind, light.color, position=np.asarray(light.position) + origin,
                      direction=light.direction)
    tiles = ImageTiles(position, flat, origin, size=8)
    index = TiledShadowRegions(light, points, tiles)
    rows, cols = np.divmod(flat, position.shape[1])
    sorted_index = TiledShadowRegions(light, points, PointChunks(points, keys=(rows // 8) * 13 + cols // 8))
    rng = np.random.default_rng(2)
    hits = 0
    for _ in range(30):
        centre = rng.uniform(-6, 6, size=3) * np.array([1.0, 1.0, 0.3]) + np.array([0, 0, 1.5]) + origin
        half = rng.uniform(0.05, 0.5, size=3)
        bounds = (centre - half, centre + half)
        with np.errstate(invalid="ignore"):
            expected = shadow_region(light, bounds, points)
        got = index.region(bounds)
        np.testing.assert_array_equal(got, expected)
        np.testing.assert_array_equal(got, sorted_index.region(bounds))
        hits += expected.sum()
    assert hits > 50  # the comparison is not vacuous
    # Most points were never looked at.
    assert index.points_tested < 0.25 * index.queries * len(points)


def test_tile_bounds_hold_exactly_their_points():
    position, flat, origin = layer_image(origin=(1e4, 2.0, -5.0))
    tiles = ImageTiles(position, flat, origin, size=8)
    points = world(position, flat, origin)
    for tile in np.unique(tiles.tile_of):
        mine = points[tiles.tile_of == tile]
        # Every point inside its tile's sphere (the sphere around the box of its points).
        assert np.all(np.linalg.norm(mine - tiles.centre[tile], axis=1) <= tiles.radius[tile] * (1 + 1e-12) + 1e-9)
    # The tile of a point is the one its pixel lies in.
    rows, cols = np.divmod(flat, position.shape[1])
    np.testing.assert_array_equal(tiles.tile_of, (rows // 8) * 13 + cols // 8)
    np.testing.assert_array_equal(tiles.points_of(np.isin(np.arange(len(tiles.centre)), [0, 14])),
                                  np.flatnonzero(np.isin(tiles.tile_of, [0, 14])))


def test_no_points():
    position, _, origin = layer_image()
    tiles = ImageTiles(position, np.zeros(0, np.int64), origin)
    assert tiles.void.all()
    assert TiledShadowRegions(LIGHTS["sun"], np.zeros((0, 3)), tiles).region((np.zeros(3), np.ones(3))).shape == (0,)


@pytest.mark.parametrize("kind", sorted(LIGHTS))
def test_regions_from_points_made_on_demand_are_the_same_and_make_few_points(kind):
    """The stage gives ``LayerPixels.world`` (a function of an index), not the layer's points:
    the same regions, and a small caster's region makes only the points of the tiles it may
    reach (a mutation making every point fails the count)."""
    position, flat, origin = layer_image(height=150, width=203)
    points = world(position, flat, origin)
    made = []

    def point_rows(index):
        made.append(len(points[index]))
        return points[index]

    light = LIGHTS[kind]
    tiles = ImageTiles(position, flat, origin, size=8)
    lazy, whole = TiledShadowRegions(light, point_rows, tiles), TiledShadowRegions(light, points, tiles)
    small = (np.array([-0.3, -0.3, 1.0]), np.array([0.3, 0.3, 1.4]))
    expected = whole.region(small)
    assert 0 < expected.sum()
    np.testing.assert_array_equal(lazy.region(small), expected)
    assert 0 < sum(made) < 0.2 * len(points)
    rng = np.random.default_rng(9)
    for _ in range(8):
        centre = rng.uniform(-6, 6, size=3) * np.array([1.0, 1.0, 0.3]) + np.array([0, 0, 1.5])
        bounds = (centre - 2.0, centre + 2.0)
        np.testing.assert_array_equal(lazy.region(bounds), whole.region(bounds))
    with pytest.raises(ValueError):
        TiledShadowRegions(light, point_rows)  # made on demand: the chunks must be given


@pytest.mark.parametrize("kind", sorted(LIGHTS))
def test_cleared_pixels_at_the_camera_only_widen_their_tiles(kind):
    """A read-back layer's uncovered pixels hold zeros (the camera, positions being camera
    relative): their tiles' bounds reach the camera, the regions stay exact, and tiles with no
    covered pixel are void."""
    position, flat, origin = layer_image(origin=(50.0, -20.0, 3.0), holes=0.3)
    uncovered = np.ones(position.shape[0] * position.shape[1], bool)
    uncovered[flat] = False
    position.reshape(-1, 3)[uncovered] = 0.0
    position[:16] = 0.0  # two rows of tiles with no covered pixel at all
    keep = np.flatnonzero(~uncovered)
    flat = keep[keep >= 16 * position.shape[1]]
    points = world(position, flat, origin)
    tiles = ImageTiles(position, flat, origin, size=8)
    assert tiles.void[:2 * 13].all() and not tiles.void[2 * 13:].all()
    light = LIGHTS[kind]
    if light.kind != "SUN":
        light = Light(light.name, light.kind, light.color, position=np.asarray(light.position) + origin,
                      direction=light.direction)
    index = TiledShadowRegions(light, points, tiles)
    rng = np.random.default_rng(4)
    for _ in range(20):
        centre = rng.uniform(-6, 6, size=3) * np.array([1.0, 1.0, 0.3]) + np.array([0, 0, 1.5]) + origin
        half = rng.uniform(0.05, 0.5, size=3)
        bounds = (centre - half, centre + half)
        np.testing.assert_array_equal(index.region(bounds), shadow_region(light, bounds, points))
