"""The oracle's forced rates per element through the real engine (issue 23's ceiling,
``tools/tiers_ceiling.py``): a combination of items at different rates renders each element's
effect at its own rate (an untagged chrome sphere judged as a prospect among them), and an item is
traced alone by giving its element only that effect."""
import os
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")

from advice_scene import advice_scene  # noqa: E402
from phrt.engine import final  # noqa: E402
from phrt.engine.runs import item_measure  # noqa: E402
from phrt.engine.runs import oracle as oracle_engine  # noqa: E402


@pytest.fixture(scope="module")
def rendered(blender):
    final.release_caches()
    scene, camera = advice_scene()
    with oracle_engine.ForcedRenderer(scene, camera) as renderer, item_measure.ItemScope({"ChromeSphere": ("reflections",)}) as scope:
        renderer.render(2, ())
        _, _, selection = renderer.render(2, ())
        ids = {name: index + 1 for index, name in enumerate(selection.names)}

        def render(effects_of, rates):
            names = scope.trace_only(effects_of)
            image, _, _ = renderer.render(2, names, rates)
            passes = renderer.last_passes
            return image, {effect: np.asarray(rate) for effect, rate in (passes.effect_rate or {}).items()}, \
                np.asarray(passes.element)

        mixed = render({"Mirror": ("reflections",), "ChromeSphere": ("reflections",), "GlassBall": ("refractions",)},
                       {"reflections": {"Mirror": 0.25, "ChromeSphere": 0.5}, "refractions": {"GlassBall": 1.0}})
        alone = render({"GlassBall": ("shadows",)}, {"shadows": {"GlassBall": 0.5}})
    yield ids, mixed, alone
    final.release_caches()


def test_each_element_at_its_own_rate(rendered):
    ids, (image, rates, element), _ = rendered
    assert np.isfinite(image).all()
    reflections, refractions = rates["reflections"], rates["refractions"]
    for name, rate in (("Mirror", 0.25), ("ChromeSphere", 0.5)):
        own = element == ids[name]
        assert own.any()
        traced = reflections[own] > 0
        assert traced.mean() > 0.5, name  # its pixels that wanted a reflection got one at its rate
        assert set(np.unique(reflections[own][traced]).tolist()) == {rate}, name
    ball = element == ids["GlassBall"]
    assert (refractions[ball] == 1.0).mean() > 0.5
    assert not (rates["shadows"] > 0).any()  # the ball is tagged for shadows: only its refraction was asked for


def test_an_item_alone_traces_only_its_effect(rendered):
    ids, _, (image, rates, element) = rendered
    assert np.isfinite(image).all()
    assert (rates["shadows"] > 0).any()  # the ball's shadow, at half rate, on what it shades
    assert set(np.unique(rates["shadows"][rates["shadows"] > 0]).tolist()) == {0.5}
    assert not (rates["refractions"] > 0).any() and not (rates["reflections"] > 0).any()
