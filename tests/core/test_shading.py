"""The shared BRDF and optics helpers (phrt_addon/scene/shading.py) against closed forms:
Fresnel, Snell refraction and total internal reflection, mirror reflection, the
BRDF's reciprocity and energy bound, light units (Cycles' conventions) and
sanitising of bad input.  No bpy."""
import numpy as np
import pytest

from phrt.phrt_addon.scene import shading
from phrt.phrt_addon.scene.snapshot import Light, Material


def unit(*components):
    vector = np.asarray(components, dtype=np.float64)
    return vector / np.linalg.norm(vector)


def incident_at(theta):
    """Unit rays travelling down onto the z = 0 plane at incidence angles ``theta`` (radians), in the xz plane."""
    theta = np.atleast_1d(theta)
    return np.stack([np.sin(theta), np.zeros_like(theta), -np.cos(theta)], axis=1)


def surface(n, normal=(0, 0, 1), view=(0, 0, 1), albedo=(0.8, 0.8, 0.8), metallic=0.0, roughness=0.5,
            transmission=0.0, ior=1.5):
    return shading.SurfaceSamples(
        position=np.zeros((n, 3)), normal=np.tile(unit(*normal), (n, 1)), view=np.tile(unit(*view), (n, 1)),
        albedo=np.tile(np.asarray(albedo, float), (n, 1)), metallic=np.full(n, metallic),
        roughness=np.full(n, roughness), transmission=np.full(n, transmission), ior=np.full(n, ior),
        emission=np.zeros((n, 3)))


# -- Fresnel -----------------------------------------------------------------

def test_fresnel_at_normal_incidence_is_f0():
    for ior in (1.33, 1.5, 2.4):
        assert shading.fresnel_dielectric(np.array([1.0]), ior)[0] == pytest.approx(((ior - 1) / (ior + 1)) ** 2)


def test_fresnel_vanishes_for_p_polarisation_at_brewster_angle():
    ior = 1.5
    brewster = np.arctan(ior)
    theta_t = np.arcsin(np.sin(brewster) / ior)
    rs = (np.cos(brewster) - ior * np.cos(theta_t)) / (np.cos(brewster) + ior * np.cos(theta_t))
    # Unpolarised reflectance at Brewster's angle is half the s-reflectance (rp = 0).
    assert shading.fresnel_dielectric(np.array([np.cos(brewster)]), ior)[0] == pytest.approx(0.5 * rs ** 2)


def test_fresnel_is_total_beyond_the_critical_angle_and_continuous_before_it():
    ior_inside_to_outside = 1.0 / 1.5
    critical = np.arcsin(ior_inside_to_outside)
    angles = np.array([critical + 0.01, np.radians(60.0), np.radians(89.0)])
    np.testing.assert_array_equal(shading.fresnel_dielectric(np.cos(angles), ior_inside_to_outside), 1.0)
    sweep = np.linspace(0.0, critical - 1e-4, 200)
    values = shading.fresnel_dielectric(np.cos(sweep), ior_inside_to_outside)
    assert np.all((values >= 0) & (values <= 1))
    assert np.all(np.diff(values) >= -1e-12)  # rises monotonically towards total reflection
    assert values[-1] > 0.8


def test_fresnel_reaches_one_at_grazing_incidence_from_outside():
    assert shading.fresnel_dielectric(np.array([1e-9]), 1.5)[0] == pytest.approx(1.0, abs=1e-6)


# -- reflection and refraction ------------------------------------------------------

def test_reflect_mirrors_about_the_normal():
    incident = incident_at(np.radians([0.0, 30.0, 89.0]))
    normal = np.tile([0.0, 0.0, 1.0], (3, 1))
    reflected = shading.reflect(incident, normal)
    np.testing.assert_allclose(reflected[:, :2], incident[:, :2])
    np.testing.assert_allclose(reflected[:, 2], -incident[:, 2])
    np.testing.assert_allclose(np.linalg.norm(reflected, axis=1), 1.0)


@pytest.mark.parametrize("ior", [1.33, 1.5, 2.4])
def test_refract_obeys_snell_law_entering_glass(ior):
    theta = np.radians(np.linspace(0.0, 89.0, 50))
    incident = incident_at(theta)
    normal = np.tile([0.0, 0.0, 1.0], (len(theta), 1))
    direction, total = shading.refract(incident, normal, np.full(len(theta), 1.0 / ior))
    assert not np.any(total)
    np.testing.assert_allclose(np.linalg.norm(direction, axis=1), 1.0)
    assert np.all(direction[:, 2] < 0)  # goes on into the glass
    sin_t = np.hypot(direction[:, 0], direction[:, 1])
    np.testing.assert_allclose(np.sin(theta), ior * sin_t, atol=1e-12)
    assert np.all(direction[:, 0] >= -1e-15)  # stays in the plane of incidence, same side


def test_refract_reports_total_internal_reflection_and_returns_the_mirror_direction():
    ior = 1.5
    critical = np.degrees(np.arcsin(1.0 / ior))  # 41.8 degrees
    theta = np.radians([10.0, critical - 0.5, critical + 0.5, 60.0, 89.0])
    # Inside the glass, travelling up to the glass/air surface whose normal (facing the ray) is -z.
    incident = incident_at(theta) * np.array([1.0, 1.0, -1.0])
    normal = np.tile([0.0, 0.0, -1.0], (len(theta), 1))
    direction, total = shading.refract(incident, normal, np.full(len(theta), ior))
    np.testing.assert_array_equal(total, [False, False, True, True, True])
    np.testing.assert_allclose(direction[total], shading.reflect(incident[total], normal[total]))
    escaped = ~total
    assert np.all(direction[escaped, 2] > 0)
    np.testing.assert_allclose(ior * np.sin(theta[escaped]), np.hypot(direction[escaped, 0], direction[escaped, 1]),
                               atol=1e-12)


def test_refract_with_matching_ior_goes_straight_through():
    incident = incident_at(np.radians([0.0, 45.0, 80.0]))
    direction, total = shading.refract(incident, np.tile([0.0, 0.0, 1.0], (3, 1)), np.ones(3))
    assert not np.any(total)
    np.testing.assert_allclose(direction, incident, atol=1e-12)


# -- the BRDF ----------------------------------------------------------------------

def test_brdf_is_zero_for_light_below_the_horizon():
    values = shading.brdf_cosine(surface(3), np.array([unit(1, 0, -0.01), unit(0, 0, -1), unit(0, 1, -1)]))
    np.testing.assert_array_equal(values, 0.0)


def test_rough_dielectric_is_close_to_lambert():
    light = np.tile(unit(0.3, 0.0, 1.0), (1, 1))
    value = shading.brdf_cosine(surface(1, albedo=(0.5, 0.5, 0.5), roughness=1.0), light)[0]
    lambert = 0.5 / np.pi * light[0, 2]
    # Diffuse is weighted by (1 - F); the rough specular adds a little on top.
    assert lambert * 0.9 < value[0] < lambert * 1.2


def test_brdf_is_reciprocal():
    rng = np.random.default_rng(7)
    n = 200
    view = shading.normalize(rng.normal(size=(n, 3)) * [1, 1, 0.3] + [0, 0, 1.2])
    light = shading.normalize(rng.normal(size=(n, 3)) * [1, 1, 0.3] + [0, 0, 1.2])
    keep = (view[:, 2] > 0.2) & (light[:, 2] > 0.2)
    view, light = view[keep], light[keep]
    for roughness, metallic in ((0.3, 0.0), (0.6, 1.0)):
        def brdf(v, l):
            samples = surface(len(v), roughness=roughness, metallic=metallic)
            samples = shading.SurfaceSamples(position=samples.position, normal=samples.normal, view=v,
                                             albedo=samples.albedo, metallic=samples.metallic,
                                             roughness=samples.roughness, transmission=samples.transmission,
                                             ior=samples.ior, emission=samples.emission)
            return shading.brdf_cosine(samples, l) / l[:, 2:3]
        np.testing.assert_allclose(brdf(view, light), brdf(light, view), rtol=1e-9)


@pytest.mark.parametrize("roughness,metallic", [(1.0, 0.0), (0.5, 0.0), (0.3, 1.0), (0.1, 0.0)])
def test_brdf_does_not_create_energy(roughness, metallic):
    """Directional albedo (the hemispherical integral of BRDF x cos) of a white surface is about <= 1.

    Lambert x (1 - F) plus GGX is not exactly energy conserving (white dielectrics at grazing view
    reach ~1.03); 5% catches the gross errors (a missing 1/pi or 1/4) this is for."""
    n_theta, n_phi = 256, 128
    theta = (np.arange(n_theta) + 0.5) / n_theta * (np.pi / 2)
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    light = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    solid_angle = (np.sin(t) * (np.pi / 2 / n_theta) * (2 * np.pi / n_phi)).ravel()
    for view_angle in (0.0, 45.0, 75.0):
        view = unit(np.sin(np.radians(view_angle)), 0.0, np.cos(np.radians(view_angle)))
        samples = surface(len(light), view=view, albedo=(1, 1, 1), roughness=roughness, metallic=metallic)
        albedo = (shading.brdf_cosine(samples, light) * solid_angle[:, None]).sum(axis=0)
        assert np.all(albedo <= 1.05), (view_angle, albedo)
        assert np.all(albedo > 0.3)


def test_transmissive_surface_has_no_diffuse_lobe():
    light = np.tile(unit(0.0, 0.0, 1.0), (1, 1))
    glass = shading.brdf_cosine(surface(1, view=(0.7, 0, 0.7), transmission=1.0, roughness=0.5), light)[0]
    plastic = shading.brdf_cosine(surface(1, view=(0.7, 0, 0.7), transmission=0.0, roughness=0.5), light)[0]
    assert np.all(glass < 0.2 * plastic)


# -- lights (Cycles units) ----------------------------------------------------------

def test_point_light_irradiance_follows_the_inverse_square_law():
    light = Light("p", "POINT", (100.0, 100.0, 100.0), position=(0.0, 0.0, 4.0))
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0], [3.0, 0.0, 4.0]])
    direction, distance, irradiance = shading.light_incidence(light, points, np.zeros(3))
    np.testing.assert_allclose(distance, [4.0, 2.0, 3.0])
    np.testing.assert_allclose(direction, [[0, 0, 1], [0, 0, 1], [-1, 0, 0]], atol=1e-12)
    expected = 100.0 / (4 * np.pi * distance ** 2)
    np.testing.assert_allclose(irradiance[:, 0], expected, rtol=1e-4)


def test_light_incidence_uses_the_callers_origin():
    """Positions relative to a far origin give the same result as world positions."""
    light = Light("p", "POINT", (50.0, 50.0, 50.0), position=(1e5 + 1.0, 2.0, 3.0))
    world = np.array([[1e5, 0.0, 0.0], [1e5 - 2.0, 1.0, 1.0]])
    origin = np.array([1e5, 0.0, 0.0])
    near = shading.light_incidence(light, world - origin, origin)
    far = shading.light_incidence(light, world, np.zeros(3))
    for a, b in zip(near, far):
        np.testing.assert_allclose(a, b, rtol=1e-9)


def test_sun_gives_constant_irradiance_and_infinite_distance():
    sun = Light("s", "SUN", (3.0, 3.0, 3.0), direction=tuple(unit(1.0, 0.0, -1.0)))
    direction, distance, irradiance = shading.light_incidence(sun, np.random.default_rng(0).normal(size=(5, 3)) * 1e4,
                                                              np.zeros(3))
    np.testing.assert_allclose(direction, np.tile(unit(-1.0, 0.0, 1.0), (5, 1)))
    assert np.all(np.isinf(distance))
    np.testing.assert_allclose(irradiance, 3.0)


def test_spot_light_is_dark_outside_its_cone_and_full_inside():
    spot = Light("s", "SPOT", (10.0, 10.0, 10.0), position=(0.0, 0.0, 5.0), direction=(0.0, 0.0, -1.0),
                 spot_size=np.radians(40.0), spot_blend=0.1)
    inside = np.array([[0.0, 0.0, 0.0]])
    outside = np.array([[5.0 * np.tan(np.radians(25.0)), 0.0, 0.0]])
    assert shading.light_incidence(spot, inside, np.zeros(3))[2][0, 0] == pytest.approx(10.0 / (4 * np.pi * 25.0),
                                                                                      rel=1e-4)
    assert shading.light_incidence(spot, outside, np.zeros(3))[2][0, 0] == 0.0


def test_area_light_emits_only_forwards_with_a_cosine():
    area = Light("a", "AREA", (10.0, 10.0, 10.0), position=(0.0, 0.0, 2.0), direction=(0.0, 0.0, -1.0))
    below = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    above = np.array([[0.0, 0.0, 4.0]])
    _, distance, irradiance = shading.light_incidence(area, below, np.zeros(3))
    assert irradiance[0, 0] == pytest.approx(10.0 / np.pi / 4.0, rel=1e-4)
    assert irradiance[1, 0] == pytest.approx(10.0 / np.pi * np.cos(np.pi / 4) / distance[1] ** 2, rel=1e-4)
    assert shading.light_incidence(area, above, np.zeros(3))[2][0, 0] == 0.0


def test_light_touching_a_surface_stays_finite():
    light = Light("p", "POINT", (1000.0, 1000.0, 1000.0), position=(0.0, 0.0, 0.0))
    direction, distance, irradiance = shading.light_incidence(light, np.zeros((1, 3)), np.zeros(3))
    assert np.all(np.isfinite(direction)) and np.all(np.isfinite(irradiance))
    values = shading.brdf_cosine(surface(1), direction) * irradiance
    assert np.all(np.isfinite(values))


# -- ambient, materials, sanitising ------------------------------------------------

def test_metal_reflects_its_base_colour_and_has_no_diffuse_ambient():
    metal = surface(1, albedo=(0.9, 0.5, 0.1), metallic=1.0, roughness=0.0)
    np.testing.assert_allclose(metal.f0[0], [0.9, 0.5, 0.1])
    diffuse, fresnel = shading.ambient(metal, (1.0, 1.0, 1.0))
    np.testing.assert_allclose(diffuse, 0.0)
    np.testing.assert_allclose(fresnel[0], [0.9, 0.5, 0.1], atol=1e-9)  # head-on view: F = F0


def test_environment_fresnel_rises_towards_grazing_for_smooth_dielectrics():
    values = [shading.ambient(surface(1, view=(np.sin(a), 0, np.cos(a)), roughness=0.0), (1, 1, 1))[1][0, 0]
              for a in np.radians([0.0, 60.0, 85.0, 89.9])]
    assert values[0] == pytest.approx(0.04)
    assert np.all(np.diff(values) > 0)
    assert values[-1] > 0.95


def test_material_table_sanitises_nan_and_out_of_range_values():
    table = shading.MaterialTable([Material("bad", base_color=(np.nan, 2.0, -1.0), metallic=np.inf,
                                            roughness=np.nan, transmission=-3.0, ior=np.nan,
                                            emission=(np.inf, np.nan, 1.0))])
    for array in (table.base_color, table.metallic, table.roughness, table.transmission, table.ior, table.emission):
        assert np.all(np.isfinite(array))
    np.testing.assert_allclose(table.base_color[0], [0.0, 1.0, 0.0])
    assert 1.0 <= table.ior[0] <= 4.0


def test_empty_material_list_gives_one_default_row():
    table = shading.MaterialTable([])
    assert table.base_color.shape == (1, 3)


def test_finite_clamps_every_bad_value():
    values = np.array([[np.nan, np.inf, -np.inf], [-1.0, 0.5, 1e9]])
    np.testing.assert_array_equal(shading.finite(values), [[0.0, 1e6, 0.0], [0.0, 0.5, 1e6]])


def test_finite_rgba_clamps_bad_rgb_sets_alpha_and_keeps_a_clean_image_in_place():
    image = np.full((3, 4, 4), 0.5, np.float32)
    assert shading.finite_rgba(image) is image  # the common case: no copy, no rewrite
    bad = image.copy()
    bad[0, 0, 0], bad[0, 1, 1], bad[1, 0, 2], bad[2, 3, 0] = np.nan, np.inf, -2.0, 3e6
    out = shading.finite_rgba(bad)
    expected = np.full((3, 4, 4), 0.5, np.float32)
    expected[..., 3] = 1.0
    expected[0, 0, 0], expected[0, 1, 1], expected[1, 0, 2], expected[2, 3, 0] = 0.0, 1e6, 0.0, 1e6
    np.testing.assert_array_equal(out, expected)
    lone_nan = image.copy()
    lone_nan[2, 2, 1] = np.nan  # a NaN alone (no other bad value to trip the test)
    assert shading.finite_rgba(lone_nan)[2, 2, 1] == 0.0
    alpha_only = image.copy()
    alpha_only[1, 1, 3] = np.nan  # a bad alpha alone: replaced by 1, the colour untouched
    np.testing.assert_array_equal(shading.finite_rgba(alpha_only)[..., :3], image[..., :3])
    assert np.all(shading.finite_rgba(alpha_only)[..., 3] == 1.0)
    assert shading.finite_rgba(np.zeros((0, 0, 4), np.float32)).shape == (0, 0, 4)


def test_normalize_leaves_zero_vectors_finite():
    result = shading.normalize(np.zeros((2, 3)))
    assert np.all(np.isfinite(result))
    assert np.all(np.isfinite(shading.normalize(np.zeros(3))))


def test_cube_face_views_are_the_signed_axis_permutations_the_glsl_lookup_computes():
    """The GLSL shadow lookup reads no per-face matrix: it computes a cube face's view from the
    point (shadowmap.cube_face_view); that must be each face's look_at view exactly."""
    from phrt.phrt_addon.raster import shadowmap
    from phrt.phrt_addon.scene.snapshot import Light
    light = Light("Lamp", "POINT", (1.0, 1.0, 1.0), position=(0.5, -1.0, 2.0))
    views = shadowmap.light_views(light, ((-5.0, -5.0, -1.0), (5.0, 5.0, 4.0)), 256)
    assert [tuple(-v.view[2, :3]) for v in views] == [tuple(map(float, f)) for f in shadowmap.CUBE_FACES]
    rng = np.random.default_rng(5)
    points = rng.normal(size=(5000, 3)) * rng.uniform(0.01, 100.0, size=(5000, 1))
    face, view = shadowmap.cube_face_view(points)
    assert set(face.tolist()) == set(range(6))
    for index, light_view in enumerate(views):
        mine = face == index
        expected = points[mine] @ light_view.view[:3, :3].T * np.array([1.0, 1.0, -1.0])
        assert np.array_equal(view[mine], expected)
        # The face seen is the one whose projection holds the point, with depth the forward axis.
        clip = np.c_[points[mine], np.ones(mine.sum())] @ light_view.view_proj_relative.T
        assert np.all(np.abs(clip[:, :2]) <= clip[:, 3:4] * (1 + 1e-12))
        np.testing.assert_allclose(clip[:, 3], view[mine][:, 2], rtol=1e-12)
        # The GLSL's clip coordinates from view 0's projection terms (engine/gpu/lighting_glsl.py shadow_lit).
        first = views[0].view_proj_relative
        np.testing.assert_allclose(-first[0, 1] * view[mine][:, 0], clip[:, 0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(first[1, 2] * view[mine][:, 1], clip[:, 1], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(first[2, 0] * view[mine][:, 2] + first[2, 3], clip[:, 2], rtol=1e-12)
