"""Hits shaded through one table per Embree set: the same material, element, normal and uv as
the hit triangle's own arrays give, over several geometries, sets and precision clusters."""
import numpy as np

from phrt.phrt_addon.scene.snapshot import Camera, Element, Material, SceneSnapshot, Settings
from phrt.phrt_addon.trace.embree_scene import TraceScene

from test_tracer import box, quad


def scattered_scene():
    """Boxes and quads of several materials and elements; a glass one (its own set: it casts no
    shadow) and a tiny box far away (its own precision cluster)."""
    materials = [Material("Grey", base_color=(0.5, 0.5, 0.5)), Material("Red", base_color=(0.9, 0.1, 0.1)),
                 Material("Glass", transmission=1.0, roughness=0.0)]
    elements = [Element(f"E{i}", f"E{i}") for i in range(4)]
    meshes = [quad("Floor", (0, 0, 0), 20, 20, "+z", material=0),
              box("A", (-2, -2, 0), (-1, -1, 1), material=1, element=0),
              box("B", (1, -2, 0), (2.5, -0.5, 2), material=0, element=1),
              box("Glass", (-1, 1, 0), (1, 2, 1.5), material=2, element=2),
              quad("Wall", (0, 5, 2), 10, 4, "-y", material=1, element=3),
              box("Far", (5e4, 5e4, 0), (5e4 + 0.01, 5e4 + 0.01, 0.01), material=1)]
    return SceneSnapshot(meshes=meshes, materials=materials, elements=elements, lights=[],
                         camera=Camera(matrix_world=np.eye(4), projection=np.eye(4), width=4, height=4),
                         world_color=(0, 0, 0), settings=Settings())


def test_hit_attributes_match_each_geometrys_own_arrays():
    scene = TraceScene(threads=1)
    try:
        scene.update(scattered_scene())
        sets = scene.sets()
        assert len(sets) >= 3  # casters, the glass, the far cluster: more than one table
        # The geometries' arrays before any table exists (the table makes them views of itself).
        own = [[(g.corner_normals.copy(), g.corner_uvs.copy(), np.array(g.tri_material), np.array(g.tri_element))
                for g in s.geometries] for s in sets]
        rng = np.random.default_rng(4)
        targets = np.r_[rng.uniform([-3, -3, 0], [3, 5, 2], size=(400, 3)),
                        np.full((20, 3), 5e4 + 0.005)]
        origins = np.array([0.0, -8.0, 6.0]) + rng.normal(0, 0.2, size=(len(targets), 3))
        origins[-20:] = [5e4 + 0.005, 5e4 + 0.005, 1.0]
        directions = targets - origins
        directions /= np.linalg.norm(directions, axis=1)[:, None]
        hits = scene.intersect(scene.to_trace(origins), directions)
        hit = np.isfinite(hits["t"])
        idx, material, element, normal, _, uv, set_index = scene.hit_surfaces(hits, hit)
    finally:
        scene.close()
    assert len(idx) > 300 and len(np.unique(set_index)) >= 2 and len(np.unique(element)) >= 4
    for k, ray in enumerate(idx):
        corner_normals, corner_uvs, tri_material, tri_element = own[hits["set"][ray]][hits["geom"][ray]]
        prim, u, v = hits["prim"][ray], float(hits["u"][ray]), float(hits["v"][ray])
        weights = np.array([1.0 - u - v, u, v])
        assert material[k] == tri_material[prim] and element[k] == tri_element[prim]
        expected = weights @ corner_normals[3 * prim:3 * prim + 3].astype(np.float64)
        np.testing.assert_allclose(normal[k], expected / np.linalg.norm(expected), atol=1e-6)
        np.testing.assert_allclose(uv[k], weights @ corner_uvs[3 * prim:3 * prim + 3].astype(np.float64), atol=1e-6)
