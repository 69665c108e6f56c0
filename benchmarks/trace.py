"""Tracer benchmark: our ``TraceScene`` queries next to raw embreex on the same rays.

A generated scene of about 200k triangles (a floor, spheres and boxes) is
uploaded once through ``TraceScene.update``; then three 640x480 ray sets are
traced, as in a frame:

- primary     camera rays through every pixel centre (nearest hit, hit data);
- shadow      occlusion rays from the primary hits that face a sun;
- reflection  mirror rays from the primary hits (incoherent, nearest hit).

Each set goes once through our wrapper (``TraceScene.intersect`` / ``occluded``:
float32 conversion, thread pool, merging of the scene sets) and once through
the very same Embree scene's ``EmbreeScene.run`` in a single call (embreex's
own serial loop), in the same run; a second ``TraceScene`` with one thread
shows the wrapper's own overhead without the pool.  Runs of the three paths
alternate, so that a slow patch of a shared machine hits them alike; the
table gives the median ms, throughput in Mrays/s and raw ms / ours ms (above
1: the pool beats one call).

No bpy; ``make bench`` calls :func:`run`.
"""
from __future__ import annotations

import time

import numpy as np

from ..phrt_addon.scene import shading
from ..phrt_addon.scene.snapshot import Camera, Material, MeshInstance, SceneSnapshot
from ..phrt_addon.trace.embree_scene import TraceScene

WIDTH, HEIGHT = 640, 480
REPEATS = 5
SPHERE_SEGMENTS, SPHERE_RINGS = 24, 12  # 528 triangles per sphere (poles are fans)
N_SPHERES, N_BOXES = 372, 300
SUN_DIRECTION = (0.35, 0.25, -1.0)
TARGET_RATIO = 0.8


def _sphere(segments, rings):
    """Unit UV sphere: positions (V,3), triangles (T,3) without degenerate pole triangles."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0.0, 2.0 * np.pi, segments + 1)[:-1]
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring_points = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    positions = np.vstack([[0.0, 0.0, 1.0], ring_points, [0.0, 0.0, -1.0]])
    top, bottom = 0, len(positions) - 1
    triangles = []
    for segment in range(segments):
        nxt = (segment + 1) % segments
        triangles.append([top, 1 + segment, 1 + nxt])
        last = 1 + (rings - 2) * segments
        triangles.append([bottom, last + nxt, last + segment])
    for ring in range(rings - 2):
        for segment in range(segments):
            nxt = (segment + 1) % segments
            a, b = 1 + ring * segments + segment, 1 + ring * segments + nxt
            c, d = a + segments, b + segments
            triangles += [[a, c, d], [a, d, b]]
    return positions, np.array(triangles, np.int32)


def _box():
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    triangles = [[a, b, c] for a, b, c, _ in quads] + [[a, c, d] for a, _, c, d in quads]
    return corners, np.array(triangles, np.int32)


def _instance(name, positions, triangles, matrix, smooth):
    positions = np.asarray(positions, np.float32)
    if smooth:
        normals = shading.normalize(positions[triangles.ravel()].astype(np.float64))
    else:
        v0, v1, v2 = (positions[triangles[:, i]].astype(np.float64) for i in range(3))
        normals = np.repeat(shading.normalize(np.cross(v1 - v0, v2 - v0)), 3, axis=0)
    count = len(triangles)
    return MeshInstance(name=name, matrix_world=matrix, positions=positions, triangles=triangles,
                        corner_normals=normals.astype(np.float32), corner_uvs=None,
                        tri_material=np.zeros(count, np.int32), tri_element=np.full(count, -1, np.int32))


def bench_scene(seed=0) -> SceneSnapshot:
    """About 200k triangles: a 40 m floor, spheres and rotated boxes scattered over it."""
    rng = np.random.default_rng(seed)
    sphere_positions, sphere_triangles = _sphere(SPHERE_SEGMENTS, SPHERE_RINGS)
    box_positions, box_triangles = _box()
    floor = np.array([[-20.0, -20.0, 0.0], [20.0, -20.0, 0.0], [20.0, 20.0, 0.0], [-20.0, 20.0, 0.0]])
    meshes = [_instance("floor", floor, np.array([[0, 1, 2], [0, 2, 3]], np.int32), np.eye(4), False)]
    for index in range(N_SPHERES):
        radius = rng.uniform(0.2, 0.9)
        matrix = np.diag([radius, radius, radius, 1.0])
        matrix[:3, 3] = [*rng.uniform(-15.0, 15.0, 2), radius]
        meshes.append(_instance(f"sphere{index}", sphere_positions, sphere_triangles, matrix, True))
    for index in range(N_BOXES):
        size = rng.uniform(0.3, 1.5, 3)
        angle = rng.uniform(0.0, np.pi)
        rotation = np.array([[np.cos(angle), -np.sin(angle), 0.0], [np.sin(angle), np.cos(angle), 0.0], [0, 0, 1]])
        matrix = np.eye(4)
        matrix[:3, :3] = rotation * size
        matrix[:3, 3] = [*rng.uniform(-15.0, 15.0, 2), size[2] / 2.0]
        meshes.append(_instance(f"box{index}", box_positions, box_triangles, matrix, False))
    camera = Camera(matrix_world=np.eye(4), projection=np.eye(4), width=WIDTH, height=HEIGHT)
    return SceneSnapshot(meshes=meshes, materials=[Material("grey")], elements=[], lights=[], camera=camera)


def camera_rays(eye=(0.0, -22.0, 9.0), target=(0.0, 0.0, 0.0), fov_degrees=60.0):
    """Pinhole rays through every pixel centre: origins (N,3), unit directions (N,3), world space."""
    eye = np.asarray(eye, float)
    forward = shading.normalize(np.asarray(target, float) - eye)
    right = shading.normalize(np.cross(forward, [0.0, 0.0, 1.0]))
    up = np.cross(right, forward)
    half = np.tan(np.radians(fov_degrees) / 2.0)
    xs = ((np.arange(WIDTH) + 0.5) / WIDTH * 2.0 - 1.0) * half * WIDTH / HEIGHT
    ys = ((np.arange(HEIGHT) + 0.5) / HEIGHT * 2.0 - 1.0) * half
    grid_x, grid_y = np.meshgrid(xs, ys)
    directions = forward + grid_x[..., None] * right + grid_y[..., None] * up
    directions = shading.normalize(directions.reshape(-1, 3))
    return np.broadcast_to(eye, directions.shape).copy(), directions


def _median_ms(functions, repeats):
    """Median ms of each function, their runs interleaved (after one warm-up run each)."""
    for function in functions:
        function()
    times = [[] for _ in functions]
    for _ in range(repeats):
        for function, samples in zip(functions, times):
            start = time.perf_counter()
            function()
            samples.append((time.perf_counter() - start) * 1000.0)
    return [float(np.median(samples)) for samples in times]


def ray_sets(trace_scene, origins_world, directions):
    """The three ray sets of a frame, in trace-frame float32 (what both paths receive)."""
    origins = trace_scene.to_trace(origins_world)
    hits = trace_scene.intersect(origins, directions)
    hit = np.isfinite(hits["t"])
    points = origins[hit] + directions[hit] * hits["t"][hit, None]
    _, _, _, normal, geometric, _, set_index = trace_scene.hit_surfaces(hits, hit)
    incoming = directions[hit]
    facing = np.where((np.sum(geometric * incoming, axis=1) < 0)[:, None], normal, -normal)
    eps = trace_scene.epsilon(points, set_index=set_index)
    to_sun = -shading.normalize(np.asarray(SUN_DIRECTION, float))
    lit = facing @ to_sun > 0
    shadow_origins = points[lit] + facing[lit] * eps[lit, None]
    shadow_directions = np.broadcast_to(to_sun, shadow_origins.shape)
    reflection_origins = points + facing * eps[:, None]
    reflection_directions = shading.reflect(incoming, facing)
    as32 = lambda array: np.ascontiguousarray(array, dtype=np.float32)  # noqa: E731
    return {
        "primary": (as32(origins), as32(directions), None),
        "shadow": (as32(shadow_origins), as32(shadow_directions), np.full(len(shadow_origins), 1e30, np.float32)),
        "reflection": (as32(reflection_origins), as32(reflection_directions), None),
    }


def _queries(trace_scene, embree_set, effect, origins, directions, dists):
    """(ours, raw, same_answers) for one ray set (raw: the same rays in the set's own frame)."""
    embree_scene = embree_set.scene
    local_origins = embree_set.local(origins)
    if effect == "shadow":
        def ours():
            return trace_scene.occluded(origins, directions, dists)

        def raw():
            return embree_scene.run(local_origins, directions, dists=dists.copy(), query="OCCLUDED")

        return ours, raw, bool(np.array_equal(ours(), np.asarray(raw()) != -1))

    def ours():
        return trace_scene.intersect(origins, directions)

    def raw():
        return embree_scene.run(local_origins, directions, output=1)

    raw_out = raw()
    raw_t = np.where(raw_out["geomID"] != -1, raw_out["tfar"], np.inf).astype(np.float32)
    return ours, raw, bool(np.array_equal(ours()["t"].astype(np.float32), raw_t))


def run(out=print, repeats=REPEATS):
    """Build the scene, trace the three ray sets three ways, print the table; returns the rows."""
    snapshot = bench_scene()
    pooled, single = TraceScene(), TraceScene(threads=1)
    try:
        upload_ms = pooled.update(snapshot)
        single.update(snapshot)
        embree_set = next(s for s in pooled.sets() if s.casts_shadow and not s.empty)
        assert len(pooled.sets()) == 1, "the bench scene is one cluster of casters"
        origins_world, directions = camera_rays()
        rows = []
        for effect, (origins, rays_directions, dists) in ray_sets(pooled, origins_world, directions).items():
            ours, raw, same = _queries(pooled, embree_set, effect, origins, rays_directions, dists)
            ours_single, _, same_single = _queries(single, embree_set, effect, origins, rays_directions, dists)
            ours_ms, single_ms, raw_ms = _median_ms((ours, ours_single, raw), repeats)
            n = len(origins)
            rows.append({"effect": effect, "rays": n, "ours_ms": ours_ms, "ours_1thread_ms": single_ms,
                         "raw_ms": raw_ms, "ours_mrays_s": n / ours_ms / 1e3, "raw_mrays_s": n / raw_ms / 1e3,
                         "ratio": raw_ms / ours_ms, "ratio_1thread": raw_ms / single_ms,
                         "same_answers": same and same_single})
    finally:
        pooled.close()
        single.close()

    version = _embreex_version()
    out(f"Trace benchmark: {snapshot.n_triangles:,} triangles in {len(snapshot.meshes)} meshes, "
        f"{WIDTH}x{HEIGHT} camera rays, {pooled.threads} worker threads, embreex {version}")
    out(f"upload + BVH build {upload_ms:.0f} ms; median of {repeats} interleaved runs per cell")
    out(f"{'effect':<11} {'rays':>8} {'ours ms':>8} {'1-thr ms':>9} {'raw ms':>7} {'ours Mray/s':>12} "
        f"{'raw Mray/s':>11} {'ours/raw':>9} {'1-thr/raw':>10} {'same':>5}")
    for row in rows:
        out(f"{row['effect']:<11} {row['rays']:>8,} {row['ours_ms']:>8.1f} {row['ours_1thread_ms']:>9.1f} "
            f"{row['raw_ms']:>7.1f} {row['ours_mrays_s']:>12.2f} {row['raw_mrays_s']:>11.2f} "
            f"{row['ratio']:>9.2f} {row['ratio_1thread']:>10.2f} {'yes' if row['same_answers'] else 'NO':>5}")
    worst = min(row["ratio"] for row in rows)
    out(f"ours/raw throughput: worst {worst:.2f} (target >= {TARGET_RATIO:.2f}: "
        f"{'met' if worst >= TARGET_RATIO else 'NOT met'})")
    return rows


def _embreex_version():
    try:
        from importlib.metadata import version
        return version("embreex")
    except Exception:  # not installed as a distribution (a bundled wheel in Blender)
        return "?"


if __name__ == "__main__":
    run()
