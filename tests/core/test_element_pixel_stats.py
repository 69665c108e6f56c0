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


@pytest.mark.parametrize("seed", range(6))
def test_a_coherent_image_summed_over_its_row_runs_matches_a_per_element_count(seed):
    """An element-id image is made of runs along rows (the fast path): rectangles and discs of
    ids over a background, depths with holes, one element's runs touching the row ends."""
    rng = np.random.default_rng(seed)
    height, width = rng.integers(20, 90, size=2)
    n = int(rng.integers(1, 30))
    image = np.full((height, width), -1)
    rows, columns = np.mgrid[:height, :width]
    for element in rng.integers(-2, n + 4, size=12):
        if rng.random() < 0.5:
            r0, c0 = rng.integers(0, height), rng.integers(0, width)
            image[r0:r0 + rng.integers(1, height), c0:c0 + rng.integers(1, width)] = element
        else:
            centre, radius = rng.uniform(0, [height, width]), rng.uniform(2, max(height, width) / 2)
            image[(rows - centre[0]) ** 2 + (columns - centre[1]) ** 2 < radius ** 2] = element
    image[:-1, -1] = image[1:, 0]  # a run ending a row and the one starting the next: the same id
    depth = rng.uniform(0.5, 50.0, size=(height, width)).astype(np.float32)
    if seed % 2:
        depth[rng.random((height, width)) < 0.02] = np.inf if seed % 4 == 1 else np.nan
    from phrt.phrt_addon.raster import gbuffer
    key = np.minimum((image + 1).ravel().astype(np.int64).view(np.uint64), np.uint64(n + 1)).view(np.int64)
    assert gbuffer.row_runs(key, width) is not None  # the run path is the one tested
    counts, centre, mean_depth = element_pixel_stats(image, n, depth)
    expected = brute_force(image, n, depth)
    assert np.array_equal(counts, expected[0])
    np.testing.assert_allclose(centre, expected[1], rtol=0, atol=1e-12)
    np.testing.assert_allclose(mean_depth, expected[2], rtol=1e-9)


@pytest.mark.parametrize("dtype", [np.uint32, np.int32, np.int64])
def test_the_gpus_unsigned_ids_give_the_statistics_of_signed_ones(dtype):
    """The resolve reads the element ids back as R32UI: no element (-1) is 0xFFFFFFFF there, and
    ids beyond the list (either kind) count for no element, on the run path and the per-pixel one."""
    rng = np.random.default_rng(7)
    n, height, width = 9, 40, 56
    coherent = np.repeat(rng.integers(-1, n + 3, size=(height, 7)), 8, axis=1)  # runs of 8
    noisy = rng.integers(-1, n + 3, size=(height, width))
    for image in (coherent, noisy):
        depth = rng.uniform(0.5, 50.0, size=(height, width)).astype(np.float32)
        depth[3, :5] = np.inf
        counts, centre, mean_depth = element_pixel_stats(image.astype(dtype), n, depth)
        expected = brute_force(image, n, depth)
        assert np.array_equal(counts, expected[0])
        np.testing.assert_allclose(centre, expected[1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(mean_depth, expected[2], rtol=1e-9)


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
