"""The rectangle a frame's traced effects can change (phrt_addon/trace/trace_rect.py): every
pixel whose surface lies in a caster's shadow region and in the scene's bounds is inside it,
and a frame read back in it is the same, pixel for pixel, as one read whole."""
import dataclasses

import numpy as np
import pytest

from phrt.phrt_addon.frame import FrameRenderer
from phrt.phrt_addon.scene.snapshot import Light
from phrt.phrt_addon.trace.element_bounds import ElementBounds
from phrt.phrt_addon.trace.shadow_region import shadow_region
from phrt.phrt_addon.raster.gbuffer import EMPTY, points_rect
from phrt.phrt_addon.trace.trace_rect import shadow_hull, union_rect

from test_frame import HEIGHT, WIDTH, ReferenceRaster, camera, mirror_scene, render


def _pixels(view, points):
    """(pixel x, pixel y, in front of the near plane) of world points."""
    clip = np.c_[points, np.ones(len(points))] @ (view.projection @ view.view_matrix).T
    w = clip[:, 3]
    front = w >= view.clip_start
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (clip[:, 0] / w + 1.0) * 0.5 * WIDTH
        y = (clip[:, 1] / w + 1.0) * 0.5 * HEIGHT
    return x, y, front


def _region_samples(rng, light, low, high, reach, n=20000):
    """Points spread over the caster's shadow region (the cylinder or the cone of its bounding
    sphere, ``reach`` long), kept where ``shadow_region`` accepts them."""
    centre, radius = (low + high) / 2.0, 0.5 * np.linalg.norm(high - low)
    lateral = rng.normal(size=(n, 3))
    lateral *= (radius * rng.uniform(0, 1, n) ** (1 / 3) / np.linalg.norm(lateral, axis=1))[:, None]
    if light.kind == "SUN":
        direction = np.asarray(light.direction) / np.linalg.norm(light.direction)
        points = centre + rng.uniform(-radius, reach, n)[:, None] * direction + lateral
    else:
        origin = np.asarray(light.position)
        target = centre + lateral  # a point of the sphere, the ray from the light through it
        direction = (target - origin) / np.linalg.norm(target - origin, axis=1)[:, None]
        distance = np.linalg.norm(centre - origin)
        points = origin + rng.uniform(max(distance - radius, 0), distance + reach, n)[:, None] * direction
    return points[shadow_region(light, (low, high), points)]


def test_every_region_point_of_the_scene_projects_inside_the_rectangle():
    """Random scenes, casters, suns and lamps, cameras looking at the caster: every point of the
    region inside the scene's bounds and in front of the camera projects inside the rectangle
    (and the rectangle is a real crop in most cases: the test is not passed by None)."""
    cropped = 0
    for seed in range(150):
        rng = np.random.default_rng(seed)
        scene_low = rng.uniform(-20, 0, 3)
        scene_high = scene_low + rng.uniform(4, 30, 3)
        low = rng.uniform(scene_low, scene_high - 1.0)
        high = low + rng.uniform(0.05, 1.0, 3)
        if seed % 2:
            light = Light("Sun", "SUN", (1.0, 1.0, 1.0), direction=tuple(rng.normal(size=3)))
        else:
            light = Light("Lamp", "POINT", (1.0, 1.0, 1.0), position=tuple(rng.uniform(scene_low - 5, scene_high + 5)))
        centre = (low + high) / 2.0
        away = rng.normal(size=3)
        eye = centre + away / np.linalg.norm(away) * rng.uniform(3.0, 25.0)
        view = camera(tuple(eye), tuple(centre + rng.normal(scale=2.0, size=3)))
        hull = shadow_hull(light, (low, high), (scene_low, scene_high))
        points = _region_samples(rng, light, low, high, float(np.linalg.norm(scene_high - scene_low)))
        points = points[np.all((points >= scene_low) & (points <= scene_high), axis=1)]
        if hull is None:
            assert light.kind != "SUN"
            continue
        rect = points_rect(view, hull, WIDTH, HEIGHT)
        x, y, front = _pixels(view, points)
        seen = front & (x >= 0) & (x < WIDTH) & (y >= 0) & (y < HEIGHT)
        if rect is None:
            continue  # the whole frame
        cropped += bool(np.any(seen))
        x0, y0, w, h = rect
        assert np.all((x[seen] >= x0) & (x[seen] < x0 + w) & (y[seen] >= y0) & (y[seen] < y0 + h)), seed
    assert cropped >= 30


def test_a_small_caster_in_front_of_the_camera_gives_a_small_rectangle():
    view = camera((0.0, -6.0, 2.0), (0.0, 0.0, 0.5))
    box = (np.array([-0.3, -0.3, 0.0]), np.array([0.3, 0.3, 0.6]))
    scene = (np.array([-20.0, -20.0, 0.0]), np.array([20.0, 20.0, 5.0]))
    sun = Light("Sun", "SUN", (1.0, 1.0, 1.0), direction=(0.3, 0.4, -1.0))
    x0, y0, w, h = points_rect(view, shadow_hull(sun, box, scene), WIDTH, HEIGHT)
    assert w * h < 0.2 * WIDTH * HEIGHT
    # A lamp inside the caster's bounding sphere: every point may be shadowed.
    assert shadow_hull(Light("Lamp", "POINT", (1.0, 1.0, 1.0), position=(0.0, 0.0, 0.3)), box, scene) is None
    # A hull wholly behind the camera: nothing, left out of a union (not dragging it to a corner).
    behind = box[0] - [0, 20, 0], box[1] - [0, 20, 0]
    assert points_rect(view, np.array([behind[0], behind[1]]), WIDTH, HEIGHT) == EMPTY
    assert union_rect([EMPTY, (50, 40, 10, 10)], WIDTH, HEIGHT) == (50, 40, 10, 10)
    assert union_rect([EMPTY], WIDTH, HEIGHT) == (0, 0, 1, 1)
    assert union_rect([(0, 0, 2, 2), None], WIDTH, HEIGHT) is None
    assert union_rect([(0, 0, 2, 2), (5, 6, 2, 2)], WIDTH, HEIGHT) == (0, 0, 7, 8)


def test_the_near_plane_is_the_projection_s_not_clip_start():
    """A viewport may give a camera whose ``clip_start`` (1 m) is not its projection's near plane
    (0.1 m, what the raster clipped at): floor points 0.6-0.8 m away, in a lamp's shadow of a
    small box, are drawn and must be inside the rectangle (found in review: they were not)."""
    from phrt.phrt_addon.raster import shadowmap
    from phrt.phrt_addon.scene.snapshot import Camera
    eye, target = np.array([0.0, 0.0, 0.5]), np.array([0.0, 2.0, 0.0])
    view_matrix = shadowmap.look_at(target - eye)
    view_matrix[:3, 3] = -(view_matrix[:3, :3] @ eye)
    view = Camera(matrix_world=np.linalg.inv(view_matrix), projection=shadowmap.perspective(np.radians(60), 0.1, 100.0),
                  width=WIDTH, height=HEIGHT, clip_start=1.0, clip_end=100.0)
    scene = (np.array([-5.0, -5.0, 0.0]), np.array([5.0, 10.0, 3.0]))
    caster = (np.array([-0.5, 0.0, 0.6]), np.array([-0.3, 0.2, 0.8]))
    lamp = Light("Lamp", "POINT", (1.0, 1.0, 1.0), position=(-0.5, -0.8, 2.8))
    rect = points_rect(view, shadow_hull(lamp, caster, scene), WIDTH, HEIGHT)
    floor = np.stack(np.meshgrid(np.linspace(-5, 5, 401), np.linspace(-5, 10, 601), [0.0]), -1).reshape(-1, 3)
    floor = floor[shadow_region(lamp, caster, floor)]
    clip = np.c_[floor, np.ones(len(floor))] @ (view.projection @ view.view_matrix).T
    x, y = (clip[:, 0] / clip[:, 3] + 1) * WIDTH / 2, (clip[:, 1] / clip[:, 3] + 1) * HEIGHT / 2
    seen = (clip[:, 3] >= 0.1) & (x >= 0) & (x < WIDTH) & (y >= 0) & (y < HEIGHT)
    assert seen.sum() > 20 and rect is not None
    x0, y0, w, h = rect
    assert np.all((x[seen] >= x0) & (x[seen] < x0 + w) & (y[seen] >= y0) & (y[seen] < y0 + h))


def test_scene_bounds_hold_every_mesh():
    snapshot = mirror_scene("RAYTRACE")
    low, high = ElementBounds().scene_bounds(snapshot)
    for mesh in snapshot.meshes:
        world = mesh.positions @ np.asarray(mesh.matrix_world)[:3, :3].T + np.asarray(mesh.matrix_world)[:3, 3]
        assert np.all(world >= low - 1e-9) and np.all(world <= high + 1e-9)


def test_scene_bounds_leave_out_vertices_no_triangle_uses():
    """A loose vertex far away (no triangle uses it) receives no shadow: not in the bounds."""
    snapshot = mirror_scene("RAYTRACE")
    expected = ElementBounds().scene_bounds(snapshot)
    mesh = snapshot.meshes[0]
    snapshot.meshes[0] = dataclasses.replace(mesh, positions=np.vstack([mesh.positions, [[500.0, -500.0, 900.0]]]),
                                             geometry_key="floor with a loose vertex")
    low, high = ElementBounds().scene_bounds(snapshot)
    assert np.allclose(low, expected[0]) and np.allclose(high, expected[1])


def test_a_frame_tracing_shadows_reads_back_a_rectangle_and_is_the_same_as_read_whole(monkeypatch):
    """The block's shadow (a sun) and the mirror: read back in their rectangle, smaller than
    the frame; the image, the rays and the traced pixels are those of the frame read whole."""
    rects = []
    read = ReferenceRaster.gbuffer
    monkeypatch.setattr(ReferenceRaster, "gbuffer", lambda self, rect=None: rects.append(rect) or read(self, rect))
    cropped, _, _ = render(mirror_scene("RAYTRACE", lights=True))
    assert cropped.stats["shadow_rays"] > 0 and cropped.stats["reflection_rays"] > 0
    assert rects[-1] is not None
    x, y, w, h = rects[-1]
    assert 0 < w * h < 0.6 * WIDTH * HEIGHT
    renderer = FrameRenderer(threads=1)
    renderer.crop_readback = False
    whole, _, _ = render(mirror_scene("RAYTRACE", lights=True), renderer)
    assert rects[-1] is None
    for key in ("shadow_rays", "reflection_rays", "rays"):
        assert whole.stats[key] == cropped.stats[key]
    np.testing.assert_array_equal(whole.passes.combined, cropped.passes.combined)


def test_rectangles_projected_together_are_those_projected_one_by_one():
    """``points_rects`` against ``points_rect`` for each set: hulls in front, straddling the near
    plane, behind the camera, off screen, filling the frame, and non-finite."""
    from phrt.phrt_addon.trace.trace_rect import points_rects
    kinds = {"in front": 0, "straddling": 0, "empty": 0, "none": 0}
    for seed in range(60):
        rng = np.random.default_rng(seed)
        eye = rng.uniform(-5, 5, 3)
        view = camera(tuple(eye), tuple(eye + rng.normal(size=3)))
        centres = eye + rng.normal(scale=rng.choice([0.3, 3.0, 30.0]), size=(12, 1, 3))
        sets = centres + rng.normal(scale=rng.uniform(0.01, 4.0, size=(12, 1, 1)), size=(12, 16, 3))
        if seed % 10 == 0:
            sets[3, 5] = np.nan
        together = points_rects(view, sets, WIDTH, HEIGHT)
        alone = [points_rect(view, points, WIDTH, HEIGHT) for points in sets]
        assert together == alone, seed
        ahead = np.array([(np.c_[s, np.ones(16)] @ (view.projection @ view.view_matrix).T)[:, 2:].sum(axis=1)
                          for s in np.nan_to_num(sets)])
        kinds["straddling"] += int(np.sum((ahead >= 0).any(axis=1) & (ahead < 0).any(axis=1)))
        kinds["in front"] += int(np.sum((ahead >= 0).all(axis=1)))
        kinds["empty"] += sum(rect == EMPTY for rect in alone)
        kinds["none"] += sum(rect is None for rect in alone)
    assert min(kinds.values()) >= 10, kinds  # every case met, many times
    view = camera((0.0, -6.0, 2.0), (0.0, 0.0, 0.5))
    assert points_rects(view, np.zeros((0, 16, 3)), WIDTH, HEIGHT) == []
    assert points_rects(view, np.zeros((2, 0, 3)), WIDTH, HEIGHT) == [EMPTY, EMPTY] == [
        points_rect(view, np.zeros((0, 3)), WIDTH, HEIGHT)] * 2
    with pytest.raises(ValueError):
        points_rects(view, np.zeros((16, 3)), WIDTH, HEIGHT)
    # Projections that are not a camera's (w <= 0 in front of the near plane, w = 0), infinite
    # points, another pad: still points_rect's answers.
    from types import SimpleNamespace
    for seed in range(40):
        rng = np.random.default_rng(100 + seed)
        odd = SimpleNamespace(projection=rng.normal(size=(4, 4)), view_matrix=np.eye(4))
        sets = rng.normal(scale=3.0, size=(6, 16, 3))
        sets[0, 0] = np.inf
        sets[1] = sets[1] * np.array([1.0, 1.0, 0.0])  # a plane of points
        pad = int(rng.integers(0, 5))
        assert points_rects(odd, sets, WIDTH, HEIGHT, pad) == [points_rect(odd, s, WIDTH, HEIGHT, pad) for s in sets]


def test_a_shadow_hull_is_kept_for_its_light_caster_and_scene():
    from phrt.phrt_addon.trace.trace_rect import ShadowHulls
    cached_shadow_hull = ShadowHulls()
    box = (np.array([-0.3, -0.3, 0.0]), np.array([0.3, 0.3, 0.6]))
    scene = (np.array([-20.0, -20.0, 0.0]), np.array([20.0, 20.0, 5.0]))
    lamp = Light("Lamp", "POINT", (1.0, 1.0, 1.0), position=(2.0, 1.0, 3.0))
    first = cached_shadow_hull(lamp, box, scene)
    np.testing.assert_array_equal(first, shadow_hull(lamp, box, scene))
    again = cached_shadow_hull(Light("Lamp", "POINT", (0.5, 0.5, 0.5), position=(2.0, 1.0, 3.0)), box, scene)
    assert again is first and not first.flags.writeable  # same values: the same hull, not recomputed
    moved = cached_shadow_hull(Light("Lamp", "POINT", (1.0, 1.0, 1.0), position=(2.0, 1.0, 3.5)), box, scene)
    np.testing.assert_array_equal(moved, shadow_hull(Light("Lamp", "POINT", (1.0, 1.0, 1.0), position=(2.0, 1.0, 3.5)),
                                                     box, scene))
    assert not np.array_equal(moved, first)
    sun = Light("Sun", "SUN", (1.0, 1.0, 1.0), direction=(2.0, 1.0, 3.0))  # same numbers, another kind
    assert not np.array_equal(cached_shadow_hull(sun, box, scene), first)
    other_sun = Light("Sun", "SUN", (1.0, 1.0, 1.0), direction=(-1.0, 0.5, -3.0), position=(2.0, 1.0, 3.0))
    np.testing.assert_array_equal(cached_shadow_hull(other_sun, box, scene), shadow_hull(other_sun, box, scene))
    for other_box, other_scene in [((box[0] + 0.5, box[1] + 0.5), scene), (box, (scene[0], scene[1] + 3.0))]:
        np.testing.assert_array_equal(cached_shadow_hull(lamp, other_box, other_scene),
                                      shadow_hull(lamp, other_box, other_scene))
    assert cached_shadow_hull(Light("Lamp", "POINT", (1.0, 1.0, 1.0), position=(0.0, 0.0, 0.3)), box, scene) is None
