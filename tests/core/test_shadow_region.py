"""The pixels a caster can shadow: the sorted-window index must give exactly the brute-force answer."""
import numpy as np
import pytest

from phrt.phrt_addon.shadow_region import ShadowRegionIndex, shadow_region
from phrt.phrt_addon.scene import Light

LIGHTS = {
    "sun": Light("Sun", "SUN", (3.0, 3.0, 3.0), direction=(-0.4, 0.5, -0.77)),
    "point": Light("Lamp", "POINT", (100.0, 100.0, 100.0), position=(1.0, -2.0, 4.0)),
    "spot": Light("Spot", "SPOT", (100.0, 100.0, 100.0), position=(-3.0, 1.0, 5.0), direction=(0.3, 0.0, -1.0)),
}


@pytest.mark.parametrize("kind", sorted(LIGHTS))
def test_index_matches_brute_force_for_many_casters(kind):
    rng = np.random.default_rng(7)
    points = rng.uniform(-10, 10, size=(20000, 3)) * np.array([1.0, 1.0, 0.2])
    light = LIGHTS[kind]
    index = ShadowRegionIndex(light, points)
    hits = 0
    for _ in range(40):  # the first queries test every point, the later ones a sorted window
        centre = rng.uniform(-6, 6, size=3) * np.array([1.0, 1.0, 0.3]) + np.array([0, 0, 1.0])
        half = rng.uniform(0.05, 1.5, size=3)
        bounds = (centre - half, centre + half)
        expected = shadow_region(light, bounds, points)
        got = index.region(bounds)
        # float32 light-space coordinates: only points within rounding of the boundary may differ
        assert np.count_nonzero(got != expected) <= 2
        hits += expected.sum()
    assert hits > 1000  # the casters do shadow something: the comparison is not vacuous


def test_light_inside_the_caster_bounds_reaches_every_point():
    points = np.random.default_rng(1).uniform(-5, 5, size=(500, 3))
    light = LIGHTS["point"]
    bounds = (np.array(light.position) - 1.0, np.array(light.position) + 1.0)
    assert ShadowRegionIndex(light, points).region(bounds).all()
