"""A, P, D from the element-id image: pixel count, centroid in NDC, mean view depth."""
import numpy as np
import pytest

from phrt.phrt_addon.raster.gbuffer import PixelGrid, element_pixel_stats


def brute_force(image, n, depth):
    height, width = image.shape
    counts, centre, mean_depth = np.zeros(n, np.int64), np.zeros((n, 2)), np.full(n, np.inf)
    for element in range(n):
        rows, columns = np.nonzero(image == element)
        counts[element] = len(rows)
        if len(rows):
            centre[element] = ((columns.mean() + 0.5) / width * 2 - 1, (rows.mean() + 0.5) / height * 2 - 1)
            values = depth[rows, columns].astype(np.float64)
            values = values[np.isfinite(values)]
            if len(values):
                mean_depth[element] = values.mean()
    return counts, centre, mean_depth


# 12 elements: per-row/column tables; 5000 on a small image: the weighted bincounts.
@pytest.mark.parametrize("n, height, width", [(12, 48, 64), (5000, 30, 40)])
def test_element_pixel_stats_match_a_per_element_count(n, height, width):
    rng = np.random.default_rng(n)
    image = rng.integers(-3, n + 3, size=(height, width))  # ids beyond the list are no element
    image[: height // 3, : width // 2] = 1  # one large element
    depth = rng.uniform(0.5, 50.0, size=(height, width)).astype(np.float32)
    depth[rng.random((height, width)) < 0.1] = np.inf
    depth[5, :] = np.nan
    counts, centre, mean_depth = element_pixel_stats(image, n, depth)
    expected = brute_force(image, n, depth)
    assert np.array_equal(counts, expected[0])
    np.testing.assert_allclose(centre, expected[1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(mean_depth, expected[2], rtol=1e-9)
    assert counts.sum() == np.count_nonzero((image >= 0) & (image < n))


def test_a_kept_grid_gives_the_same_statistics_as_a_new_one_at_every_size():
    """The grid a replay keeps follows the frame size (a kept grid of another size would put
    every centroid elsewhere)."""
    grid = PixelGrid()
    rng = np.random.default_rng(3)
    for height, width in [(48, 64), (48, 64), (30, 80), (48, 64)]:
        image = rng.integers(-2, 9, size=(height, width))
        depth = rng.uniform(0.5, 50.0, size=(height, width)).astype(np.float32)
        kept = element_pixel_stats(image, 8, depth, grid)
        fresh = brute_force(image, 8, depth)
        assert np.array_equal(kept[0], fresh[0])
        np.testing.assert_allclose(kept[1], fresh[1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(kept[2], fresh[2], rtol=1e-9)
    assert not grid.coordinates(48, 64)[0].flags.writeable
