"""phrt_addon/scene/lights.py: the light kinds, the spot cone and the soft radius that the numpy
shading and the GPU light packing share."""
import numpy as np
import pytest

from phrt.phrt_addon.scene import lights, shading
from phrt.phrt_addon.scene.snapshot import Light


def test_each_blender_light_type_has_its_code_and_an_unknown_type_lights_as_a_point():
    codes = {kind: int(lights.kind(Light("l", kind, (1.0, 1.0, 1.0)))) for kind in ("SUN", "POINT", "SPOT", "AREA")}
    assert codes == {"SUN": 0, "POINT": 1, "SPOT": 2, "AREA": 3}
    assert lights.kind(Light("l", "MESH_EMITTER", (1.0, 1.0, 1.0))) is lights.LightKind.POINT


def test_an_unknown_type_is_shaded_as_a_point_light():
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, -2.0]])
    odd = Light("l", "MESH_EMITTER", (5.0, 5.0, 5.0), position=(0.0, 0.0, 3.0))
    point = Light("l", "POINT", (5.0, 5.0, 5.0), position=(0.0, 0.0, 3.0))
    origin = np.zeros(3)
    for a, b in zip(shading.light_incidence(odd, points, origin), shading.light_incidence(point, points, origin)):
        np.testing.assert_array_equal(a, b)


def test_the_spot_cone_spans_the_blend_of_half_the_spot_angle():
    spot = Light("s", "SPOT", (1.0, 1.0, 1.0), spot_size=np.radians(60.0), spot_blend=0.25)
    outer, inner = lights.spot_cone(spot)
    assert outer == pytest.approx(np.cos(np.radians(30.0)))
    assert inner == pytest.approx(outer + 0.25 * (1.0 - outer))
    hard = Light("s", "SPOT", (1.0, 1.0, 1.0), spot_size=np.radians(60.0), spot_blend=0.0)
    outer, inner = lights.spot_cone(hard)
    assert inner > outer  # a blend of 0 still leaves an edge to fade over (no division by zero)


def test_the_soft_radius_has_a_floor():
    assert lights.soft_radius(Light("p", "POINT", (1.0, 1.0, 1.0), radius=0.0)) == lights.MIN_RADIUS
    assert lights.soft_radius(Light("p", "POINT", (1.0, 1.0, 1.0), radius=0.25)) == 0.25
