"""The trace stage's per-pixel arithmetic done component by component (np.take, np.compress,
1-D products) gives what the plain (n, 3) numpy it replaced gives: face normals against a
pixel-by-pixel reference, the row helpers against fancy indexing, dot / normalize / ray
epsilon against einsum and max."""
import numpy as np
import pytest

from phrt.phrt_addon.frame_types import rows_of
from phrt.phrt_addon.raster.gbuffer import GBufferLayer, encode_face_normals
from phrt.phrt_addon.raster.normals import geometric_normals
from phrt.phrt_addon.scene import shading
from phrt.phrt_addon.trace.embree_scene import EPSILON_ULPS, FLOAT32_EPS, ray_epsilon


def _layer(rng, height=9, width=11, with_geometric=False):
    """A layer of two elements and two materials on tilted planes, with holes, a NaN position
    and shading normals that sometimes face away."""
    ys, xs = np.mgrid[0:height, 0:width].astype(np.float32)
    element = np.where(xs < width // 2, 0, 1).astype(np.int64)
    element[rng.random((height, width)) < 0.1] = -1
    material = np.where(ys < height // 2, 0, 1).astype(np.int32)
    depth = 5.0 + 0.3 * xs + 0.7 * ys * (element == 1) + rng.normal(0, 0.01, (height, width))
    position = np.stack([xs - width / 2, ys - height / 2, -depth], axis=-1).astype(np.float32)
    position[2, 3] = np.nan
    covered = rng.random((height, width)) > 0.15
    normal = rng.normal(size=(height, width, 3)).astype(np.float32)
    normal[..., 2] += 1.5
    layer = GBufferLayer(covered=covered, position=position, normal=normal, element=element.astype(np.int32),
                         material=material, roughness=np.zeros((height, width), np.float32),
                         albedo=np.ones((height, width, 3), np.float32), metallic=np.zeros((height, width), np.float32))
    if with_geometric:
        faces = rng.normal(size=(height, width, 3))
        faces[rng.random((height, width)) < 0.1] = 0.0  # degenerate: none found there
        layer.geometric_normal = encode_face_normals(faces)
    return layer


def _reference_normals(layer, flat, view):
    """The rule of ``geometric_normals`` one pixel at a time, in plain Python over float64."""
    height, width = layer.covered.shape
    position = layer.position.reshape(-1, 3).astype(np.float64)
    out = np.zeros((len(flat), 3))
    for k, p in enumerate(flat):
        y, x = divmod(int(p), width)
        towards = -np.asarray(view[k], np.float64)
        if layer.geometric_normal is not None:
            stored = layer.geometric_normal.reshape(-1, 4)[p]
            normal = stored[:3].astype(np.float64) / 127.5 - 1.0
            length = np.sqrt(normal @ normal)
            found = bool(stored[3] >= 128) and length > 0.5
            normal = normal / length if found else np.zeros(3)
        else:
            def same(q):
                return bool(layer.covered.ravel()[q]) and layer.material.ravel()[q] == layer.material.ravel()[p] \
                    and layer.element.ravel()[q] == layer.element.ravel()[p]

            def along(step, coordinate, limit):
                forward = position[min(p + step, height * width - 1)] - position[p]
                backward = position[p] - position[max(p - step, 0)]
                f_ok = coordinate + 1 < limit and same(min(p + step, height * width - 1))
                b_ok = coordinate > 0 and same(max(p - step, 0))
                f_len = forward @ forward if f_ok else np.inf
                b_len = backward @ backward if b_ok else np.inf
                return (forward if f_len <= b_len else backward), (f_ok or b_ok)

            ax, ok_x = along(1, x, width)
            ay, ok_y = along(width, y, height)
            normal = np.cross(ax, ay)
            length = np.sqrt(normal @ normal)
            found = ok_x and ok_y and length > 0 and np.isfinite(length)
            normal = normal / length if found else np.zeros(3)
        side = normal @ towards
        normal = -normal if side < 0 else normal
        shade = layer.normal.reshape(-1, 3)[p].astype(np.float64)
        shade = -shade if shade @ towards < 0 else shade
        usable = found and abs(side) > 1e-6 and normal @ shade > 0 and np.all(np.isfinite(normal))
        out[k] = normal if usable else towards
    return out


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("with_geometric", [False, True])
def test_face_normals_match_the_pixel_by_pixel_rule(seed, with_geometric):
    rng = np.random.default_rng(seed)
    layer = _layer(rng, with_geometric=with_geometric)
    flat = np.flatnonzero(layer.covered.ravel())
    view = shading.normalize(layer.position.reshape(-1, 3)[flat].astype(np.float64))
    view = np.nan_to_num(view, nan=0.0) + np.array([0.0, 0.0, -1e-3])
    got = geometric_normals(layer, flat, view)
    want = _reference_normals(layer, flat, view)
    assert got.shape == (len(flat), 3) and got.dtype == np.float64
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    # The camera direction is used somewhere (holes, edges) and the facets elsewhere.
    camera = np.all(np.isclose(got, -view), axis=1)
    assert camera.any() and not camera.all()


def test_face_normals_of_no_pixels():
    layer = _layer(np.random.default_rng(0))
    assert geometric_normals(layer, np.zeros(0, np.int64), np.zeros((0, 3))).shape == (0, 3)


def test_rows_of_is_indexing():
    rng = np.random.default_rng(1)
    array = rng.normal(size=(50, 3))
    mask = rng.random(50) < 0.4
    index = rng.integers(-50, 50, 30)
    np.testing.assert_array_equal(rows_of(array, mask), array[mask])
    np.testing.assert_array_equal(rows_of(array, index), array[index])
    np.testing.assert_array_equal(rows_of(array, slice(3, 9)), array[3:9])
    broadcast = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (50, 3))  # a sun's directions
    np.testing.assert_array_equal(rows_of(broadcast, mask), broadcast[mask])
    assert rows_of(array, []).shape == (0, 3) == array[[]].shape
    with pytest.raises(IndexError):
        rows_of(array, mask[:-1])  # np.compress would cut the array silently
    with pytest.raises(IndexError):
        rows_of(array, np.array([50]))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_dot_and_normalize_match_einsum(dtype):
    rng = np.random.default_rng(2)
    a = rng.normal(size=(200, 3)).astype(dtype)
    b = rng.normal(size=(200, 3)).astype(dtype)
    a[5] = [np.nan, 1.0, 0.0]
    a[6] = 0.0
    np.testing.assert_allclose(shading.dot(a, b), np.einsum("ij,ij->i", a, b), rtol=1e-6 if dtype == np.float32
                               else 1e-14, equal_nan=True)
    assert shading.dot(a, b).dtype == np.einsum("ij,ij->i", a, b).dtype
    length = np.sqrt(np.einsum("ij,ij->i", a, a))[:, None]
    np.testing.assert_allclose(shading.normalize(a), a / np.maximum(length, 1e-30), rtol=1e-6, equal_nan=True)
    assert np.all(shading.normalize(a)[6] == 0.0)
    grid = rng.normal(size=(4, 5, 3))  # images of vectors and other widths keep working
    np.testing.assert_allclose(np.linalg.norm(shading.normalize(grid), axis=-1), 1.0)
    np.testing.assert_allclose(shading.dot(a[:, :2], b[:, :2]), np.einsum("ij,ij->i", a[:, :2], b[:, :2]), rtol=1e-6)


def test_ray_epsilon_takes_the_largest_coordinate():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(100, 3)) * 10.0 ** rng.integers(-3, 5, (100, 1))
    points[7] = [np.nan, 0.0, 1.0]
    extent = rng.uniform(0.1, 100.0, 100)
    magnitude = np.max(np.abs(points), axis=-1)
    want = EPSILON_ULPS * FLOAT32_EPS * (magnitude + 1e-3 * extent) + 1e-7 * extent
    got = ray_epsilon(points, extent)
    assert np.array_equal(got, want, equal_nan=True) and np.isnan(got[7])
    view = rng.uniform(0.0, 1e4, 100)
    want = EPSILON_ULPS * FLOAT32_EPS * (np.maximum(magnitude, view) + 1e-3 * extent) + 1e-7 * extent
    np.testing.assert_array_equal(ray_epsilon(points, extent, view)[np.isfinite(magnitude)],
                                  want[np.isfinite(magnitude)])


@pytest.mark.parametrize("seed", range(3))
def test_layer_pixels_keep_each_pixels_face_normal_across_calls(seed):
    """Asked in overlapping parts (lights' regions), with repeats, by index or mask, a layer's
    face normals are those of one call over every pixel."""
    from types import SimpleNamespace
    from phrt.phrt_addon.frame_types import LayerPixels
    rng = np.random.default_rng(seed)
    layer = _layer(rng, height=14, width=17)
    camera = SimpleNamespace(ortho=False, forward=np.array([0.0, 0.0, -1.0]))
    materials = SimpleNamespace(ior=np.ones(2))
    pixels = LayerPixels(layer, np.zeros(3), camera, materials)
    everything = np.arange(len(pixels))
    view = np.nan_to_num(pixels.view_directions(everything), nan=0.0) + np.array([0.0, 0.0, -1e-3])
    want = geometric_normals(layer, pixels.flat, view)
    for _ in range(4):
        part = rng.choice(everything, size=len(pixels) // 3)  # repeats within a call
        np.testing.assert_array_equal(pixels.geometric_normals(part, view[part]), want[part])
    mask = rng.random(len(pixels)) < 0.5
    np.testing.assert_array_equal(pixels.geometric_normals(mask, view[mask]), want[mask])
    np.testing.assert_array_equal(pixels.geometric_normals(slice(None), view), want)


def test_face_normals_stored_in_eight_bits_decode_within_a_degree():
    """The G-buffer pass's encoding (``encode_face_normals``, GLSL twin in engine/gpu/gbuffer.py)
    decodes to within a degree of the unit normal; zero, NaN and infinite vectors are marked
    not found and leave towards the camera."""
    rng = np.random.default_rng(7)
    faces = rng.normal(size=(400, 3))
    faces[:3] = [[0.0, 0.0, 0.0], [np.nan, 1.0, 0.0], [np.inf, 0.0, 0.0]]
    faces[3:] *= 10.0 ** rng.uniform(-30, 30, size=(397, 1))  # any length
    stored = encode_face_normals(faces)
    assert stored.dtype == np.uint8 and stored.shape == (400, 4)
    assert stored[:3, 3].tolist() == [0, 0, 0] and np.all(stored[3:, 3] == 255)
    layer = _layer(np.random.default_rng(0), height=20, width=20)
    layer.geometric_normal = np.zeros((20, 20, 4), np.uint8)
    flat = np.random.default_rng(1).permutation(400)
    layer.geometric_normal.reshape(-1, 4)[flat] = stored
    layer.normal = np.zeros_like(layer.normal)
    unit = faces[3:] / np.linalg.norm(faces[3:], axis=1, keepdims=True)
    # The shading normal on the face's side, the camera on that side too: the face is kept.
    layer.normal.reshape(-1, 3)[flat[3:]] = unit
    view = np.zeros((400, 3))
    view[:, 2] = 1.0
    view[3:] = -unit
    got = geometric_normals(layer, flat, view)
    cosine = np.sum(got[3:] * unit, axis=1)
    assert np.all(cosine > np.cos(np.radians(1.0)))
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(got[:3], -view[:3])
