"""Reflections and refractions leave as one batch of bounce rays (stage.py ``_trace_bounces``):
each effect's traced values, its rays and its elements' rays are what tracing it alone gives."""
import dataclasses

import numpy as np

from phrt.phrt_addon.frame_types import LayerPixels
from phrt.phrt_addon.scene import shading
from phrt.phrt_addon.trace.element_bounds import ElementBounds
from phrt.phrt_addon.trace.embree_scene import TraceScene
from phrt.phrt_addon.trace.stage import TraceStage

from test_trace_rates import glass_scene


def trace(snapshot, gbuffer, effects):
    materials = shading.MaterialTable(snapshot.materials)
    layers = {name: LayerPixels(getattr(gbuffer, name), gbuffer.origin, snapshot.camera, materials)
              for name in ("opaque", "transparent")}
    n = len(snapshot.elements)
    stage = TraceStage(threads=1)
    try:
        return stage.run(snapshot, layers, materials, np.ones(n, bool), ElementBounds()(snapshot),
                         effects={effect: np.full(n, effect in effects) for effect in
                                  ("shadows", "reflections", "refractions")})
    finally:
        stage.close()


def test_one_batch_gives_each_effect_what_it_gives_alone(monkeypatch):
    snapshot, gbuffer = glass_scene()
    sent = []  # every ray handed to Embree (no shadows traced: all are the bounces' own)
    for name in ("intersect", "occluded"):
        query = getattr(TraceScene, name)
        monkeypatch.setattr(TraceScene, name, lambda self, origins, *a, _query=query, **k: (
            sent.append(len(origins)), _query(self, origins, *a, **k))[1])
    # The pane reflects too: reflections from both layers and the refraction in one batch.
    glass = len(snapshot.elements) - 1
    snapshot.elements[glass] = dataclasses.replace(snapshot.elements[glass], reflections=True)
    # Bounces beyond the first: the rays of later levels keep their part's label.
    snapshot.settings = dataclasses.replace(snapshot.settings, max_bounces=3)
    both = trace(snapshot, gbuffer, ("reflections", "refractions"))
    # Every ray the batch sent, through every bounce, is counted to one of the two effects.
    assert both.counters.reflection_rays + both.counters.refraction_rays == sum(sent)
    reflections = trace(snapshot, gbuffer, ("reflections",))
    refractions = trace(snapshot, gbuffer, ("refractions",))
    assert set(both.traced.reflection) == {"opaque", "transparent"} == set(reflections.traced.reflection)
    for layer in ("opaque", "transparent"):
        for got, alone in zip(both.traced.reflection[layer], reflections.traced.reflection[layer]):
            np.testing.assert_array_equal(got, alone)
    for got, alone in zip(both.traced.refraction, refractions.traced.refraction):
        np.testing.assert_array_equal(got, alone)
    assert both.counters.reflection_rays == reflections.counters.reflection_rays > 0
    assert both.counters.refraction_rays == refractions.counters.refraction_rays > 0
    np.testing.assert_allclose(both.item_rays[:, 1], reflections.item_rays[:, 1])
    np.testing.assert_allclose(both.item_rays[:, 2], refractions.item_rays[:, 2])
    # The batch's time is shared out, all of it: each effect gets a part.
    assert both.counters.reflection_ms > 0 and both.counters.refraction_ms > 0
