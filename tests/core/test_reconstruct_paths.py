"""The reconstruction's shortcuts give what its filter gives (``phrt_addon/trace/rates.py``):

- a binary field (shadow visibility) takes the value its same-element neighbours agree on
  without weighing them: wherever the weighted filter fills a pixel, the same value;
- the filter reads the guide over a window around the missing pixels or over the whole image,
  and a pixel's value depends on its neighbours only, not on which other pixels were wanted;
- ``gather.take_rows`` / ``compress_rows`` are ``a[index]`` on contiguous and strided arrays.
"""
import numpy as np
import pytest

from phrt.phrt_addon.gather import compress_rows, take_rows
from phrt.phrt_addon.raster.gbuffer import GBufferLayer
from phrt.phrt_addon.trace.rates import reconstruct, traced_subset
from phrt.phrt_addon.trace.reconstruction_guide import Guide, layer_guide

H, W = 40, 56


def scene_layer(seed):
    """A layer with three elements at different depths, a tilted floor, creases and holes."""
    rng = np.random.default_rng(seed)
    layer = GBufferLayer.empty(W, H)
    rows, cols = np.mgrid[:H, :W]
    layer.covered[:] = rng.random((H, W)) > 0.03
    depth = 4.0 + 0.04 * rows + 0.01 * cols
    box = (rows > 8) & (rows < 25) & (cols > 10) & (cols < 30)
    depth = np.where(box, 2.5 + 0.3 * (cols > 20), depth)  # a crease inside the box
    pole = (cols >= 40) & (cols < 43)
    depth = np.where(pole, 1.5, depth)
    direction = np.stack([(cols - W / 2) / W, (rows - H / 2) / H, -np.ones((H, W))], axis=-1)
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    layer.position[:] = (direction * depth[..., None]).astype(np.float32)
    normal = np.zeros((H, W, 3))
    normal[..., 1] = 1.0
    normal[box] = [0.0, 0.0, 1.0]
    normal[box & (cols > 20)] = [0.6, 0.0, 0.8]
    normal[pole] = [1.0, 0.0, 0.0]
    layer.normal[:] = normal
    layer.element[:] = np.where(box, 0, np.where(pole, 1, -1))
    layer.material[:] = np.where(layer.covered, np.where(box | pole, 1, 0), -1)
    layer.element[~layer.covered] = -1
    return layer


def shadow_of(layer, seed):
    """A binary visibility: a few blocky shadows, the pole lit."""
    rng = np.random.default_rng(seed + 100)
    blocks = rng.random((H // 4 + 1, W // 4 + 1)) > 0.5
    visibility = np.repeat(np.repeat(blocks, 4, axis=0), 4, axis=1)[:H, :W].astype(float)
    visibility[layer.element == 1] = 1.0
    return visibility.ravel()


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("rate", [0.25, 0.5])
def test_a_binary_field_takes_where_it_is_filled_the_value_the_weighted_filter_gives(seed, rate):
    """Visibility v in {0, 1} (the shortcut) and 0.25 + 0.5 v (weighted: not binary) must agree
    wherever the weighted filter fills a pixel; the shortcut fills every pixel it fills."""
    layer = scene_layer(seed)
    guide = layer_guide(layer)
    visibility = shadow_of(layer, seed)
    wanted = np.flatnonzero(layer.covered.ravel())
    for frame in range(4):
        cast = traced_subset(wanted, rate, H, W, frame)
        traced = wanted[cast]
        binary = reconstruct(wanted, traced, visibility[traced], guide, W, rate)
        weighted = reconstruct(wanted, traced, 0.25 + 0.5 * visibility[traced], guide, W, rate)
        assert set(weighted.flat) <= set(binary.flat)
        both = np.isin(binary.flat, weighted.flat)
        np.testing.assert_allclose(0.25 + 0.5 * binary.values[both], weighted.values, rtol=0, atol=1e-6)
        # The lit pole never takes the shadowed box's or floor's values.
        pole = layer.element.ravel()[binary.flat] == 1
        assert pole.any() and np.all(binary.values[pole] == 1.0)


@pytest.mark.parametrize("seed", range(3))
def test_a_pixels_value_does_not_depend_on_the_other_wanted_pixels(seed):
    """The box's pixels alone (a small window) and the whole layer (the image as the window)
    reconstruct the box's pixels alike, RGB and binary."""
    layer = scene_layer(seed)
    rng = np.random.default_rng(seed)
    wanted = np.flatnonzero(layer.covered.ravel())
    box = wanted[layer.element.ravel()[wanted] == 0]
    colour = rng.random((H * W, 3))
    for rate in (0.25, 0.5):
        for values in (colour, shadow_of(layer, seed)):
            whole_cast = traced_subset(wanted, rate, H, W, seed)
            box_cast = traced_subset(box, rate, H, W, seed)
            whole = reconstruct(wanted, wanted[whole_cast], values[wanted[whole_cast]], layer_guide(layer), W, rate)
            part = reconstruct(box, box[box_cast], values[box[box_cast]], layer_guide(layer), W, rate)
            assert len(part.flat) > 0.9 * len(box)
            at = np.searchsorted(whole.flat, part.flat)
            np.testing.assert_array_equal(whole.flat[at], part.flat)
            np.testing.assert_allclose(whole.values[at], part.values, rtol=0, atol=1e-12)


def test_rows_are_taken_alike_from_contiguous_and_strided_arrays():
    rng = np.random.default_rng(0)
    base = rng.random((H, W, 4)).astype(np.float32)
    strided = base[..., :3].reshape(-1, 3)
    assert not strided.flags.c_contiguous
    index = rng.integers(0, H * W, 500)
    mask = rng.random(H * W) > 0.6
    for array in (strided, np.ascontiguousarray(strided), base[..., 3].reshape(-1)):
        np.testing.assert_array_equal(take_rows(array, index), array[index])
        np.testing.assert_array_equal(compress_rows(mask, array), array[mask])
        assert take_rows(array, index[:0]).shape == (0,) + array.shape[1:]


def test_a_half_rate_pixel_never_reads_two_pixels_away_when_quarter_rate_ones_are_settled():
    """Rates per pixel in one call: quarter-rate pixels the binary shortcut settles must not
    leave a half-rate pixel of the same parity class reading pixels 2 away."""
    size = 10
    guide = Guide.of(np.full(size * size, 5.0), np.tile([0.0, 0.0, 1.0], (size * size, 1)), np.zeros(size * size, int))
    at = {(3, 3): 0.25, (3, 4): 0.25, (5, 5): 0.5, (5, 7): 0.5}
    wanted = np.array(sorted(r * size + c for r, c in at))
    rate = np.array([at[divmod(int(p), size)] for p in wanted])
    traced = np.array([3 * size + 4, 5 * size + 7])
    for values in (np.array([1.0, 1.0]), np.array([0.5, 0.7])):
        out = reconstruct(wanted, traced, values, guide, size, rate)
        assert 5 * size + 5 in out.unfilled  # its only traced pixel of the element is 2 away
        assert 3 * size + 3 in out.flat  # a quarter-rate pixel reaches (3, 4)


@pytest.mark.parametrize("seed", range(3))
def test_rates_per_pixel_keep_each_value_independent_of_the_other_wanted_pixels(seed):
    """A rate per pixel (the box at quarter rate, the rest at half): the box's pixels alone and
    the whole layer reconstruct the box's pixels alike, binary and RGB."""
    layer = scene_layer(seed)
    wanted = np.flatnonzero(layer.covered.ravel())
    box_of = layer.element.ravel() == 0
    rate_of = np.where(box_of, 0.25, 0.5)
    colour = np.random.default_rng(seed).random((H * W, 3))
    for values in (colour, shadow_of(layer, seed)):
        results = []
        for part in (wanted, wanted[box_of[wanted] | (np.arange(len(wanted)) % 3 == 0)]):
            cast = traced_subset(part, rate_of[part], H, W, seed)
            results.append(reconstruct(part, part[cast], values[part[cast]], layer_guide(layer), W, rate_of[part]))
        whole, part = results
        mine = box_of[part.flat]
        at = np.searchsorted(whole.flat, part.flat[mine])
        np.testing.assert_array_equal(whole.flat[at], part.flat[mine])
        np.testing.assert_allclose(whole.values[at], part.values[mine], rtol=0, atol=1e-12)


def test_a_non_finite_normal_weighs_like_no_normal():
    """A NaN normal (normalize() of a zero vector on the GPU) at some pixels: the others
    reconstruct as with a zero normal there (no NaN weight spoiling a neighbourhood)."""
    layer = scene_layer(1)
    rng = np.random.default_rng(3)
    broken = rng.random((H, W)) < 0.03
    nan_layer, zero_layer = scene_layer(1), scene_layer(1)
    nan_layer.normal[broken] = np.nan
    zero_layer.normal[broken] = 0.0
    wanted = np.flatnonzero(layer.covered.ravel())
    colour = rng.random((H * W, 3))
    for rate in (0.25, 0.5):
        cast = traced_subset(wanted, rate, H, W, 2)
        traced = wanted[cast]
        with_nan = reconstruct(wanted, traced, colour[traced], layer_guide(nan_layer), W, rate)
        with_zero = reconstruct(wanted, traced, colour[traced], layer_guide(zero_layer), W, rate)
        np.testing.assert_array_equal(with_nan.flat, with_zero.flat)
        np.testing.assert_array_equal(with_nan.values, with_zero.values)
