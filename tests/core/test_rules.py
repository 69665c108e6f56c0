"""The rules of phrt_addon/scene/rules.py, one home per physical question, on their own and as the
material table and the tracer's scene use them.  The raster side of each rule is checked by
rendering through Blender (tests/integration/test_rules_parity.py)."""
import numpy as np
import pytest

from phrt.phrt_addon.scene import rules, shading
from phrt.phrt_addon.scene.snapshot import Element, Material
from phrt.phrt_addon.trace.embree_scene import TraceScene

from test_tracer import box, diffuse, quad, snapshot

# (material, transparent, casts a shadow)
CASES = [
    (Material("opaque"), False, True),
    (Material("glass", transmission=1.0, roughness=0.0), True, False),
    (Material("curtain", transmission=0.3), True, True),
    (Material("frosted", transmission=0.6), True, False),
    (Material("card", alpha=0.3), True, False),
    (Material("veil", alpha=0.8), True, True),
    (Material("card_glass", alpha=0.5, transmission=1.0), True, False),
    (Material("gold_glass", metallic=1.0, transmission=1.0), False, True),
    (Material("nan", transmission=np.nan, alpha=np.nan, metallic=np.nan), False, True),
]


@pytest.mark.parametrize("material,transparent,shadow", CASES, ids=[case[0].name for case in CASES])
def test_one_rule_decides_transparency_and_shadow_casting(material, transparent, shadow):
    assert material.is_transparent == transparent
    assert material.casts_shadow == shadow
    table = shading.MaterialTable([material])
    assert bool(table.transparent[0]) == transparent
    assert bool(table.casts_shadow[0]) == shadow


def test_shadow_transmittance_adds_what_alpha_leaves_and_what_refracts():
    np.testing.assert_allclose(rules.shadow_transmittance(0.3, 0.0, 1.0), 0.3)
    np.testing.assert_allclose(rules.shadow_transmittance(0.0, 0.0, 0.25), 0.75)
    np.testing.assert_allclose(rules.shadow_transmittance(1.0, 0.0, 0.5), 1.0)
    np.testing.assert_allclose(rules.shadow_transmittance(1.0, 1.0, 1.0), 0.0)


@pytest.mark.parametrize("material,transparent,shadow", CASES, ids=[case[0].name for case in CASES])
def test_shadow_rays_are_blocked_exactly_by_the_materials_that_cast_shadows(material, transparent, shadow):
    snap = snapshot([quad("floor", (0, 0, 0), 10, 10, "+z", material=0),
                     box("caster", (-1, -1, 1), (1, 1, 1.2), material=1)], [diffuse("floor"), material])
    scene = TraceScene(threads=1)
    try:
        scene.update(snap)
        start = scene.to_trace([[0.0, 0.0, 0.01]])
        blocked = scene.occluded(start, np.array([[0.0, 0.0, 1.0]]), np.array([1e30]))[0]
        hits = scene.intersect(start, np.array([[0.0, 0.0, 1.0]]))
    finally:
        scene.close()
    assert blocked == shadow
    assert np.isfinite(hits["t"][0])  # radiance rays see every material


@pytest.mark.parametrize("ior,expected", [(np.nan, 1.5), (0.5, 1.0), (-3.0, 1.0), (1.0, 1.0), (1.45, 1.45),
                                          (4.0, 4.0), (11.0, 4.0), (np.inf, 4.0)])
def test_ior_is_clamped_by_the_documented_rule(ior, expected):
    assert rules.clamp_ior(ior) == pytest.approx(expected)
    assert shading.MaterialTable([Material("m", ior=ior)]).ior[0] == pytest.approx(expected)


def test_an_ior_of_one_reflects_nothing_at_any_angle():
    """Schlick's approximation would give an IOR-1 surface (F0 = 0) a bright grazing rim."""
    f0 = np.zeros((5, 3))
    cosines = np.array([1.0, 0.5, 0.1, 0.01, 0.0])
    np.testing.assert_array_equal(shading.fresnel_schlick(f0, cosines), 0.0)
    np.testing.assert_array_equal(shading.environment_fresnel(f0, cosines, np.zeros(5)), 0.0)
    np.testing.assert_array_equal(shading.fresnel_dielectric(cosines, 1.0), 0.0)
    # Ordinary dielectrics and metals keep Schlick's grazing reflectance of 1.
    glass = np.full((1, 3), shading.f0_dielectric(1.5))
    assert shading.fresnel_schlick(glass, np.array([0.0]))[0, 0] == pytest.approx(1.0)


def test_k_zero_is_not_a_candidate():
    assert Element("a", "a", candidate=True, priority=1.0).is_candidate
    assert not Element("a", "a", candidate=True, priority=0.0).is_candidate
    assert not Element("a", "a", candidate=True, priority=np.nan).is_candidate
    assert not Element("a", "a", candidate=False, priority=3.0).is_candidate


# -- textures ---------------------------------------------------------------------------------------

def checker(height, width, seed=0):
    return np.random.default_rng(seed).uniform(0.0, 1.0, (height, width, 4)).astype(np.float32)


def test_a_texture_sampled_at_texel_centres_returns_the_texels():
    image = checker(4, 8)
    ys, xs = np.mgrid[0:4, 0:8]
    uv = np.stack([(xs.ravel() + 0.5) / 8, (ys.ravel() + 0.5) / 4], axis=1)
    np.testing.assert_allclose(rules.sample_texture(image, uv), image.reshape(-1, 4), atol=1e-6)


def test_sampling_is_bilinear_between_texel_centres():
    image = checker(4, 8)
    uv = np.array([[1.0 / 8, 0.5 / 4], [0.5 / 8, 1.0 / 4], [1.0 / 8, 1.0 / 4]])
    expected = [(image[0, 0] + image[0, 1]) / 2, (image[0, 0] + image[1, 0]) / 2,
                image[:2, :2].reshape(-1, 4).mean(axis=0)]
    np.testing.assert_allclose(rules.sample_texture(image, uv), expected, atol=1e-6)


def test_sampling_wraps_on_both_axes():
    image = checker(4, 8)
    uv = np.array([[0.3, 0.6], [1.3, -0.4], [-2.7, 5.6], [0.0, 0.0], [1.0, 1.0]])
    samples = rules.sample_texture(image, uv)
    np.testing.assert_allclose(samples[1], samples[0], atol=1e-5)
    np.testing.assert_allclose(samples[2], samples[0], atol=1e-5)
    np.testing.assert_allclose(samples[4], samples[3], atol=1e-6)
    # (0, 0) lies between the four corner texels.
    np.testing.assert_allclose(samples[3], image[[0, 0, -1, -1], [0, -1, 0, -1]].mean(axis=0), atol=1e-6)


def test_non_finite_coordinates_read_zero():
    image = checker(4, 8)
    uv = np.array([[np.nan, 0.3], [np.inf, 0.3], [0.0, 0.3], [0.2, -np.inf], [0.2, 0.0]])
    samples = rules.sample_texture(image, uv)
    assert np.all(np.isfinite(samples))
    np.testing.assert_array_equal(samples[0], samples[2])
    np.testing.assert_array_equal(samples[1], samples[2])
    np.testing.assert_array_equal(samples[3], samples[4])
    corners = rules.texture_coordinates(np.array([[np.nan, 0.5], [0.25, np.inf], [1.0, 2.0]]), 3)
    np.testing.assert_array_equal(corners, [[0.0, 0.5], [0.25, 0.0], [1.0, 2.0]])


def test_a_mesh_without_uvs_reads_zero_coordinates():
    np.testing.assert_array_equal(rules.texture_coordinates(None, 6), np.zeros((6, 2)))
    with pytest.raises(ValueError):
        rules.texture_coordinates(np.zeros((5, 2)), 6)


def test_prepared_texture_is_finite_rgba_float32_and_left_alone_when_small():
    image = checker(16, 8)
    assert rules.prepare_texture(image) is image
    bad = image.copy()
    bad[0, 0] = [np.nan, np.inf, -np.inf, 0.5]
    prepared = rules.prepare_texture(bad)
    np.testing.assert_array_equal(prepared[0, 0], [0.0, 1.0, 0.0, 0.5])
    grey = rules.prepare_texture(np.full((2, 3), 0.25))
    assert grey.shape == (2, 3, 4) and grey.dtype == np.float32
    np.testing.assert_array_equal(grey[0, 0], [0.25, 0.25, 0.25, 1.0])


def test_a_large_texture_is_averaged_down_by_the_smallest_integer_factor():
    image = checker(10, 21)
    prepared = rules.prepare_texture(image, max_size=8)  # factor 3: 10 x 21 -> 4 x 7
    assert prepared.shape == (4, 7, 4)
    np.testing.assert_allclose(prepared[1, 2], image[3:6, 6:9].reshape(-1, 4).mean(axis=0), atol=1e-6)
    # The last row of blocks wraps around to the first rows (the sampler wraps too).
    np.testing.assert_allclose(prepared[3, 0], image[[9, 0, 1]][:, 0:3].reshape(-1, 4).mean(axis=0), atol=1e-6)
    big = rules.prepare_texture(np.ones((rules.MAX_TEXTURE_SIZE + 1, 3, 4), np.float32))
    assert big.shape == ((rules.MAX_TEXTURE_SIZE + 2) // 2, 2, 4)
    np.testing.assert_allclose(big, 1.0)
