"""``TraceStage.run(..., rates=...)`` (issue 23): effects traced at half and quarter rate cast
about that share of their rays, the untraced pixels are reconstructed from the G-buffer close
to the full-rate result, and no traced value crosses into another element.

The G-buffer is ray cast with Embree and shaded by the numpy reference raster (as in
test_frame.py): a floor, a mirror (element 0) beside a rough metal patch (element 2) in the
same plane, both reflecting a red emissive wall, and a block (element 1) casting a shadow."""
import numpy as np
import pytest

from phrt.phrt_addon.frame_types import LayerPixels
from phrt.phrt_addon.raster.reference_raster import ReferenceRaster
from phrt.phrt_addon.scene import shading
from phrt.phrt_addon.scene.snapshot import Element, Light, Material
from phrt.phrt_addon.trace.element_bounds import ElementBounds
from phrt.phrt_addon.trace.stage import TraceStage

from test_frame import mirror_scene, ray_cast_gbuffer
from test_tracer import quad

MIRROR, BLOCK, ROUGH = 0, 1, 2


def scene(frame=1):
    snapshot = mirror_scene("RAYTRACE")
    snapshot.materials.append(Material("Rough", base_color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.35))
    snapshot.elements.append(Element("Rough", "Rough", shadows=False, reflections=True, refractions=False))
    snapshot.meshes.append(quad("Rough", (2.0, 1.0, 0.01), 2.0, 2.0, "+z", material=4, element=ROUGH))
    # The sun behind the block: its shadow falls towards the camera, in view.
    snapshot.lights[0] = Light("Sun", "SUN", (3.0, 3.0, 3.0), direction=(0.5, -0.7, -0.6))
    snapshot.frame = frame
    return snapshot


def trace(snapshot, gbuffer, rates=None):
    materials = shading.MaterialTable(snapshot.materials)
    layers = {name: LayerPixels(getattr(gbuffer, name), gbuffer.origin, snapshot.camera, materials)
              for name in ("opaque", "transparent")}
    stage = TraceStage(threads=1)
    try:
        return stage.run(snapshot, layers, materials, np.ones(len(snapshot.elements), bool),
                         ElementBounds()(snapshot), rates=rates)
    finally:
        stage.close()


def image(flat, values, shape):
    out = np.full(shape + values.shape[1:], np.nan)
    out.reshape((-1,) + values.shape[1:])[flat] = values
    return out


@pytest.fixture(scope="module")
def full():
    snapshot = scene()
    gbuffer = ray_cast_gbuffer(snapshot)
    return snapshot, gbuffer, trace(snapshot, gbuffer)


def values_at(result_pair, flat):
    where, values = result_pair
    position = np.searchsorted(where, flat)
    assert np.array_equal(where[position], flat)
    return values[position]


@pytest.mark.parametrize("rate, ray_share, reflection_mad, shadow_mad", [
    # Measured over frames 0-3 (96x72, 417 reflecting pixels, 244 shadow-region pixels):
    # reflection rays 0.499-0.501 of full at half rate, 0.243-0.258 at quarter; shadow rays
    # 0.500 and 0.234-0.266; mean abs difference from full rate of the reflected radiance
    # (values up to 2.0) 0.0026-0.0027 (half) and 0.0040-0.0043 (quarter), of the shadow
    # visibility (0 or 1) 0.032-0.034 and 0.064-0.073, of the shaded image 0.0005 / 0.0009.
    (0.5, 0.5, 0.006, 0.06),
    (0.25, 0.25, 0.009, 0.11),
])
@pytest.mark.parametrize("frame", [0, 1, 2, 3])
def test_a_reduced_rate_casts_its_share_of_the_rays_and_reconstructs_close_to_full_rate(
        full, rate, ray_share, reflection_mad, shadow_mad, frame):
    snapshot, gbuffer, reference = full
    snapshot.frame = frame
    result = trace(snapshot, gbuffer, {"reflections": np.full(3, rate), "shadows": np.full(3, rate)})
    counters, base = result.counters, reference.counters
    assert counters.reflection_rays == pytest.approx(ray_share * base.reflection_rays, rel=0.1)
    assert counters.shadow_rays == pytest.approx(ray_share * base.shadow_rays, rel=0.1)
    assert result.element_rays.sum() == pytest.approx(counters.rays)
    assert result.element_rays[BLOCK] == pytest.approx(counters.shadow_rays)
    assert result.element_rays[MIRROR] + result.element_rays[ROUGH] == pytest.approx(counters.reflection_rays)

    shape = gbuffer.opaque.covered.shape
    where, values = result.traced.reflection["opaque"]
    full_where, full_values = reference.traced.reflection["opaque"]
    assert np.isfinite(values).all() and values.shape[1] == 3
    assert len(where) >= 0.99 * len(full_where) and np.isin(where, full_where).all()
    # The pixels that got rays this frame have exactly the full-rate values (the same rays).
    cast = traced_pixel_mask_at(shape, rate, frame, where)
    np.testing.assert_allclose(values[cast], values_at(reference.traced.reflection["opaque"], where[cast]),
                               rtol=1e-6, atol=1e-7)
    difference = np.abs(values - values_at(reference.traced.reflection["opaque"], where))
    assert difference.mean() < reflection_mad
    shadow = result.traced.shadow_visibility[("opaque", 0)]
    full_shadow = reference.traced.shadow_visibility[("opaque", 0)]
    assert np.isfinite(shadow[1]).all() and ((shadow[1] >= 0) & (shadow[1] <= 1)).all()
    # At a reduced rate only the pixels cast are tested for facing the light: the reconstructed
    # ones include pixels facing away (the full rate leaves those out; their light is zero).
    assert np.isin(full_shadow[0], shadow[0]).mean() > 0.99
    both = np.isin(shadow[0], full_shadow[0])
    assert np.abs(shadow[1][both] - values_at(full_shadow, shadow[0][both])).mean() < shadow_mad
    # A shadow that is half traced still darkens where the full one does.
    assert (shadow[1] < 0.5).sum() > 0.6 * (full_shadow[1] < 0.5).sum() > 30

    shaded = ReferenceRaster(snapshot, gbuffer).shade(result.traced)
    full_shaded = ReferenceRaster(snapshot, gbuffer).shade(reference.traced)
    assert np.isfinite(shaded).all()
    assert np.abs(shaded - full_shaded)[..., :3].mean() < 0.003


def traced_pixel_mask_at(shape, rate, frame, flat):
    from phrt.phrt_addon.trace.rates import traced_pixel_mask
    return traced_pixel_mask(shape[0], shape[1], rate, frame).ravel()[flat]


@pytest.mark.parametrize("rate", [0.5, 0.25])
def test_no_reflected_value_crosses_into_the_neighbouring_element(full, rate):
    """The rough patch beside the mirror, in the same plane (same depth and normal), reflects
    the red wall weakly; the mirror strongly.  Every reconstructed value of an element lies
    within the range of the values traced on that element this frame, so the mirror's red never
    reaches the rough patch."""
    snapshot, gbuffer, reference = full
    element = gbuffer.opaque.element.ravel()
    for frame in range(4):
        snapshot.frame = frame
        result = trace(snapshot, gbuffer, {"reflections": np.full(3, rate)})
        where, values = result.traced.reflection["opaque"]
        cast = traced_pixel_mask_at(gbuffer.opaque.covered.shape, rate, frame, where)
        for own, other in ((MIRROR, ROUGH), (ROUGH, MIRROR)):
            mine = element[where] == own
            low, high = values[mine & cast].min(axis=0), values[mine & cast].max(axis=0)
            assert (values[mine] >= low - 1e-9).all() and (values[mine] <= high + 1e-9).all()
        full_rough = values_at(reference.traced.reflection["opaque"], where[element[where] == ROUGH])
        assert values[element[where] == ROUGH][:, 0].max() <= full_rough[:, 0].max() + 1e-9
    # The mirror's traced red is far above anything the rough patch reflects: mixing would show.
    assert values[element[where] == MIRROR][:, 0].max() > 3 * full_rough[:, 0].max()


def test_the_rate_pass_shows_each_pixels_rate(full):
    snapshot, gbuffer, reference = full
    snapshot.frame = 5
    result = trace(snapshot, gbuffer, {"reflections": np.array([0.25, 1.0, 0.5])})
    element = gbuffer.opaque.element
    assert result.rate.shape == element.shape and result.rate.dtype == np.float32
    reflected = result.effect_rate["reflections"]
    where = result.traced.reflection["opaque"][0]
    got = np.zeros(element.size, bool)
    got[where] = True
    got = got.reshape(element.shape)
    assert set(np.unique(reflected[got & (element == MIRROR)])) == {0.25}
    assert set(np.unique(reflected[got & (element == ROUGH)])) == {0.5}
    assert (reflected[~got] == 0).all()
    # The block's shadows are at full rate where its region got traced visibility.
    shadow_where = result.traced.shadow_visibility[("opaque", 0)][0]
    assert (result.effect_rate["shadows"].ravel()[shadow_where] == 1.0).all()
    assert (result.rate == np.maximum.reduce(list(result.effect_rate.values()))).all()
    assert set(np.unique(result.rate)) <= {0.0, 0.25, 0.5, 1.0}
    # Full rate everywhere: the pass is 1 exactly where a traced term replaced the raster.
    assert set(np.unique(reference.rate)) == {0.0, 1.0}


def test_full_rate_rates_change_nothing(full):
    snapshot, gbuffer, reference = full
    result = trace(snapshot, gbuffer, {"reflections": np.ones(3), "shadows": np.ones(3)})
    assert result.counters.rays == reference.counters.rays
    for key, (where, values) in reference.traced.shadow_visibility.items():
        np.testing.assert_array_equal(result.traced.shadow_visibility[key][0], where)
        np.testing.assert_array_equal(result.traced.shadow_visibility[key][1], values)
    np.testing.assert_array_equal(result.traced.reflection["opaque"][0], reference.traced.reflection["opaque"][0])


def test_an_unsupported_rate_is_refused(full):
    snapshot, gbuffer, _ = full
    with pytest.raises(ValueError, match="unsupported trace rate"):
        trace(snapshot, gbuffer, {"reflections": np.array([0.3, 1.0, 1.0])})


def glass_scene():
    """The scene behind a glass pane (element 3) between the camera and the mirror: the pane is
    the transparent layer (ray cast alone), the rest the opaque layer."""
    import dataclasses

    from phrt.phrt_addon.raster.gbuffer import GBuffer

    snapshot = scene()
    snapshot.materials.append(Material("Glass", base_color=(0.9, 0.95, 1.0), roughness=0.0, transmission=1.0,
                                       ior=1.45))
    snapshot.elements.append(Element("Glass", "Glass", shadows=False, reflections=False, refractions=True))
    pane = quad("Glass", (0.5, -1.5, 1.2), 3.0, 1.6, "-y", material=len(snapshot.materials) - 1, element=3)
    opaque = ray_cast_gbuffer(snapshot)
    transparent = ray_cast_gbuffer(dataclasses.replace(snapshot, meshes=[pane])).opaque
    snapshot.meshes.append(pane)
    return snapshot, GBuffer(opaque=opaque.opaque, transparent=transparent, origin=opaque.origin,
                             view_depth=np.minimum(opaque.view_depth, ray_cast_gbuffer(
                                 dataclasses.replace(snapshot, meshes=[pane])).view_depth))


@pytest.mark.parametrize("rate, mad", [
    # Measured over frames 0-3 (2495 pane pixels, refracted radiance mean 0.42, max 2.05):
    # refraction rays 0.500 (half) and 0.247-0.252 (quarter) of full; mean abs difference from
    # full rate 0.0150-0.0151 and 0.0398-0.0404 (median 0).  Larger than the reflections': what
    # is seen through the flat pane has edges (block, mirror, wall) its G-buffer guide cannot
    # show, so the reconstruction blurs them.
    (0.5, 0.025),
    (0.25, 0.06),
])
def test_refractions_at_a_reduced_rate(rate, mad):
    snapshot, gbuffer = glass_scene()
    assert gbuffer.transparent.covered.sum() > 300
    reference = trace(snapshot, gbuffer)
    full_where, full_values = reference.traced.refraction
    assert len(full_where) == gbuffer.transparent.covered.sum()
    for frame in range(4):
        snapshot.frame = frame
        result = trace(snapshot, gbuffer, {"refractions": np.full(4, rate)})
        assert result.counters.refraction_rays == pytest.approx(rate * reference.counters.refraction_rays, rel=0.1)
        where, values = result.traced.refraction
        assert np.isfinite(values).all() and len(where) >= 0.99 * len(full_where)
        difference = np.abs(values - values_at(reference.traced.refraction, where)).mean()
        assert difference < mad, (rate, frame, difference, full_values.max())
        assert set(np.unique(result.effect_rate["refractions"])) == {0.0, rate}


@pytest.mark.parametrize("rate", [1.0, 0.5])
def test_every_lights_shadow_rays_as_one_batch_give_each_light_its_own_result(rate):
    """The lights' shadow rays of a layer leave as one batch (``TraceStage._trace_shadows``): each
    light gets the visibility, owners, ray count and per-item rays it gets traced alone (the other
    lights casting no shadow), at full and at a reduced rate, with a third light under the floor
    that only a few pixels face."""
    lights = [Light("Sun", "SUN", (3.0, 3.0, 3.0), direction=(0.5, -0.7, -0.6)),
              Light("Lamp", "POINT", (60.0, 60.0, 60.0), position=(0.4, -1.6, 2.2)),
              Light("Under", "POINT", (60.0, 60.0, 60.0), position=(1.5, 0.0, -3.0))]
    snapshot = scene()
    snapshot.lights = lights
    gbuffer = ray_cast_gbuffer(snapshot)
    rates = {"shadows": np.full(len(snapshot.elements), rate)}
    together = trace(snapshot, gbuffer, rates)
    assert together.counters.shadow_rays > 0
    alone_rays = np.zeros(len(snapshot.elements))
    alone_count = 0
    for index in range(len(lights)):
        snapshot.lights = [light if i == index else Light(light.name, light.kind, light.color, light.position,
                                                          light.direction, cast_shadows=False)
                           for i, light in enumerate(lights)]
        alone = trace(snapshot, gbuffer, rates)
        alone_rays += alone.item_rays[:, 0]
        alone_count += alone.counters.shadow_rays
        for key in [key for key in alone.traced.shadow_visibility if key[1] == index]:
            for mine, theirs in zip(together.traced.shadow_visibility[key], alone.traced.shadow_visibility[key]):
                assert np.array_equal(mine, theirs)
            owners, owners_alone = together.traced.shadow_owners[key], alone.traced.shadow_owners[key]
            assert np.array_equal(owners[0], owners_alone[0]) and np.array_equal(owners[1], owners_alone[1])
            assert owners[2] == owners_alone[2]
            assert all(np.array_equal(a, b) for a, b in zip(owners[3], owners_alone[3]))
        assert {key for key in together.traced.shadow_visibility if key[1] == index} == \
            {key for key in alone.traced.shadow_visibility if key[1] == index}
    assert {0, 1} <= {key[1] for key in together.traced.shadow_visibility}  # the batch held several lights
    assert together.counters.shadow_rays == alone_count
    assert np.allclose(together.item_rays[:, 0], alone_rays)
