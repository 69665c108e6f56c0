"""How the raster pass draws meshes: shared vertices, spatial chunks, frustum culling."""
import numpy as np
import pytest

from phrt.phrt_addon.raster import draw_chunks


def _perspective(fov_y=1.0, aspect=4 / 3, near=0.1, far=100.0):
    f = 1.0 / np.tan(fov_y / 2)
    return np.array([[f / aspect, 0, 0, 0], [0, f, 0, 0],
                     [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)], [0, 0, -1, 0]])


def test_shared_vertices_merge_only_corners_equal_in_vertex_normal_and_coordinate():
    corners = np.array([0, 1, 2, 2, 1, 3, 0, 1, 2])
    normals = np.tile([0.0, 0.0, 1.0], (9, 1)).astype(np.float32)
    uvs = np.zeros((9, 2), np.float32)
    normals[6] = (0.0, 1.0, 0.0)  # corner 6 is vertex 0 with another normal (a hard edge)
    uvs[7] = (0.5, 0.0)  # corner 7 is vertex 1 across a UV seam
    vertex_of_corner, first = draw_chunks.shared_vertices(corners, normals, uvs)
    # Every corner's vertex has the corner's own attributes: nothing drawn changes.
    assert np.array_equal(corners[first][vertex_of_corner], corners)
    assert np.array_equal(normals[first][vertex_of_corner], normals)
    assert np.array_equal(uvs[first][vertex_of_corner], uvs)
    assert len(first) == 6  # 0, 1, 2, 3 + the two seam corners
    assert list(vertex_of_corner[:6]) == [0, 1, 2, 2, 1, 3]  # numbered in order of first use
    # -0.0 and 0.0 differ in bits: kept apart (a merge must never change a bit).
    normals[3] = (-0.0, 0.0, 1.0)
    assert len(draw_chunks.shared_vertices(corners, normals, uvs)[1]) == 7


def test_shared_vertices_of_a_smooth_grid_are_its_vertices():
    n = 30
    x, y = np.meshgrid(np.arange(n), np.arange(n))
    index = (y * n + x)[:-1, :-1].ravel()
    triangles = np.concatenate([np.stack([index, index + 1, index + n], 1),
                                np.stack([index + 1, index + n + 1, index + n], 1)])
    corners = triangles.reshape(-1)
    normals = np.tile([0.0, 0.0, 1.0], (len(corners), 1)).astype(np.float32)
    uvs = np.stack([corners % n, corners // n], 1).astype(np.float32) / n
    vertex_of_corner, first = draw_chunks.shared_vertices(corners, normals, uvs)
    assert len(first) == n * n  # six times fewer vertices than corners
    assert np.array_equal(corners[first][vertex_of_corner], corners)
    assert draw_chunks.shared_vertices(np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 2)))[1].size == 0


def test_chunks_hold_every_triangle_once_inside_their_box_and_are_compact():
    rng = np.random.default_rng(3)
    positions = rng.uniform(-50, 50, size=(30000, 3))
    triangles = rng.integers(0, len(positions), size=(20000, 3))
    # Triangles made of nearby vertices: sort vertices so consecutive ones are close.
    positions = positions[draw_chunks.morton_order(positions)]
    triangles = np.sort(triangles, axis=1)
    triangles[:, 1] = np.minimum(triangles[:, 0] + 1, len(positions) - 1)
    triangles[:, 2] = np.minimum(triangles[:, 0] + 2, len(positions) - 1)
    wanted = rng.permutation(len(triangles))[:15000]
    parts = draw_chunks.chunks(positions, triangles, wanted, size=1000)
    assert len(parts) == 15
    got = np.concatenate([part for part, _ in parts])
    assert np.array_equal(np.sort(got), np.sort(wanted))
    total_volume = np.prod(np.ptp(positions, axis=0))
    volumes = []
    for part, box in parts:
        assert len(part) <= 1000
        points = positions[triangles[part]].reshape(-1, 3)
        assert (points >= box[0]).all() and (points <= box[1]).all()
        volumes.append(np.prod(box[1] - box[0]))
    # Morton order keeps most chunks to a small part of the mesh's box (a chunk across a
    # jump of the curve may be larger); an unordered cut would span it all.
    assert np.median(volumes) < 0.2 * total_volume
    unordered = positions[triangles[wanted[:1000]]].reshape(-1, 3)
    assert np.prod(np.ptp(unordered, axis=0)) > 0.8 * total_volume


def test_a_chunk_with_a_non_finite_vertex_gets_an_infinite_box_and_is_never_culled():
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0]], float)
    triangles = np.array([[0, 1, 2], [1, 3, 2]])
    (part, box), = draw_chunks.chunks(positions, triangles, np.arange(2))
    assert np.isinf(box[0, 0]) and np.isinf(box[1, 0])
    far_away = np.eye(4)
    far_away[:3, 3] = (1e6, 1e6, 1e6)
    assert not draw_chunks.boxes_outside(_perspective() @ far_away, box[None])[0]


def test_boxes_outside_the_frustum_are_never_ones_with_a_visible_point():
    rng = np.random.default_rng(11)
    clip = _perspective()
    view = np.eye(4)
    view[:3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    matrix = clip @ view
    centres = rng.uniform(-30, 30, size=(3000, 3))
    half = rng.uniform(0.01, 5.0, size=(3000, 3))
    boxes = np.stack([centres - half, centres + half], axis=1)
    outside = draw_chunks.boxes_outside(matrix, boxes)
    # Sample each box densely: a culled box has no sample inside the frustum.
    samples = boxes[:, 0:1, :] + rng.uniform(0, 1, size=(3000, 200, 3)) * (boxes[:, 1:2, :] - boxes[:, 0:1, :])
    h = np.concatenate([samples, np.ones((3000, 200, 1))], axis=2) @ matrix.T
    inside = (np.abs(h[..., :3]) <= h[..., 3:4]).all(axis=2).any(axis=1)
    assert not (outside & inside).any()
    # And it culls: most boxes that show no sample are outside.
    assert outside.sum() > 0.7 * (~inside).sum()


@pytest.mark.parametrize("where, expected", [
    ((0.0, 0.0, -10.0), False),  # in front of the camera
    ((0.0, 0.0, 10.0), True),  # behind it
    ((0.0, 0.0, -200.0), True),  # beyond the far plane
    ((40.0, 0.0, -10.0), True),  # to the side
    ((0.0, 0.0, 0.0), False),  # around the camera itself
])
def test_boxes_outside_known_cases(where, expected):
    box = np.array([np.subtract(where, 0.5), np.add(where, 0.5)])
    assert draw_chunks.boxes_outside(_perspective(), box[None])[0] == expected


def test_boxes_outside_with_huge_coordinates_stays_finite_and_correct():
    # A camera far from the origin: the raster pass draws relative to the camera, so the
    # matrix carries the offset; a box at the camera's place is visible, one behind is not.
    offset = np.eye(4)
    offset[:3, 3] = (-1e7, -1e7, -1e7)
    boxes = np.array([[[1e7 - 1, 1e7 - 1, 1e7 - 20], [1e7 + 1, 1e7 + 1, 1e7 - 18]],
                      [[1e7 - 1, 1e7 - 1, 1e7 + 18], [1e7 + 1, 1e7 + 1, 1e7 + 20]]])
    with np.errstate(all="raise"):
        assert list(draw_chunks.boxes_outside(_perspective() @ offset, boxes)) == [False, True]
