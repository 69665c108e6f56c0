"""The selection's knobs beside the paper's equations (phrt_addon/select/heuristic.py): the greedy
order, the error-aware relevance, a budget given between the modes, the oracle's forced
selection; and the error-aware relevance's estimates (phrt_addon/select/benefit.py).  No bpy."""
import types

import numpy as np
import pytest

from phrt.phrt_addon.scene.snapshot import Material
from phrt.phrt_addon.select import benefit, heuristic
from phrt.phrt_addon.scene import shading
from phrt.phrt_addon.select.cost_model import CostModel
from phrt.phrt_addon.select.heuristic import select
from phrt.phrt_addon.select.selection_terms import FrameElements, SelectionSettings


def frame(n, **fields):
    base = dict(names=[f"e{i}" for i in range(n)], area_px=np.full(n, 10), frame_px=1000,
                centre_ndc=np.zeros((n, 2)), distance=np.ones(n))
    base.update(fields)
    return FrameElements(**base)


def test_relevance_per_ms_order_takes_cheap_relevant_elements_first():
    # e0: R 1.0 for 10 ms; e1, e2: R 0.6 for 5 ms each.  T = 10 ms.
    elements = frame(3, area_px=np.array([100, 60, 60]))
    costs = np.array([10.0, 5.0, 5.0])
    paper = select(elements, None, SelectionSettings(mode="HYBRID", selection_weight=0.0), time_left_ms=10.0,
                   element_ms=costs)
    per_ms = select(elements, None, SelectionSettings(mode="HYBRID", selection_weight=0.0, order="relevance_per_ms"),
                    time_left_ms=10.0, element_ms=costs)
    assert paper.selected.tolist() == [True, False, False]
    assert per_ms.selected.tolist() == [False, True, True]
    assert per_ms.order == "relevance_per_ms" and paper.order == "relevance"


def test_error_relevance_weights_visibility_by_benefit_and_keeps_i_meaningful():
    # Equal visibility; e1's traced image differs 10x more per pixel than e0's.
    elements = frame(2, benefit=np.array([0.05, 0.5]))
    paper = select(elements, {"e0"}, SelectionSettings(mode="HYBRID", selection_weight=0.5), time_left_ms=5.0,
                   element_ms=np.array([4.0, 4.0]))
    error = select(elements, {"e0"}, SelectionSettings(mode="HYBRID", selection_weight=0.5, relevance="error"),
                   time_left_ms=5.0, element_ms=np.array([4.0, 4.0]))
    np.testing.assert_allclose(paper.V, [1.0, 1.0])
    np.testing.assert_allclose(error.V, [1.0, 1.0])  # the logged V stays the paper's
    np.testing.assert_allclose(error.terms.weighted_visibility, [0.1, 1.0])
    np.testing.assert_allclose(error.R, [0.5 + 0.1, 1.0])  # S*I + normalised V*benefit
    assert paper.selected.tolist() == [True, False]  # the paper keeps last frame's element
    assert error.selected.tolist() == [False, True]
    assert [row["benefit"] for row in error.rows()] == pytest.approx([0.1, 1.0])
    assert "benefit" not in paper.rows()[0]


def test_budget_at_leaves_that_fraction_of_tracing_every_visible_candidate():
    elements = frame(4, area_px=np.array([10, 10, 10, 0]))
    costs = np.array([10.0, 20.0, 30.0, 40.0])  # the invisible one does not count
    model = CostModel(stage_prior_ms={"raster": 50.0, "select": 1.0, "composite": 9.0})
    result = select(elements, None, SelectionSettings(mode="HYBRID", budget_at=0.5), model, element_ms=costs)
    assert result.time_left_ms == pytest.approx(30.0)
    assert result.budget_ms == pytest.approx(60.0 + 30.0)
    assert result.predicted_trace_ms <= 30.0
    raytrace = select(elements, None, SelectionSettings(mode="RAYTRACE", budget_at=0.5), model, element_ms=costs)
    assert raytrace.selected.tolist() == [True, True, True, False]
    with pytest.raises(ValueError):
        SelectionSettings(budget_at=1.2)
    with pytest.raises(ValueError):
        SelectionSettings(relevance="beauty")
    with pytest.raises(ValueError):
        SelectionSettings(order="random")


def test_forced_selection_replaces_the_choice_but_not_the_terms():
    elements = frame(3, area_px=np.array([10, 10, 0]))
    result = select(elements, None, SelectionSettings(mode="HYBRID"), time_left_ms=0.0, element_ms=np.ones(3))
    assert not result.selected.any()
    forced = heuristic.force_selection(result, {"e1", "e2"})
    assert forced.selected.tolist() == [False, True, False]  # e2 is not visible
    assert forced.reason == ["over_budget", "", "not_visible"]
    assert forced.predicted_trace_ms == 1.0
    np.testing.assert_array_equal(forced.R, result.R)
    assert forced.time_left_ms == result.time_left_ms


# -- the error-aware relevance's estimates -------------------------------------------------------

def test_prior_ranks_a_mirror_above_a_matte_surface_before_either_is_traced():
    materials = shading.MaterialTable([Material("Mirror", base_color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.0),
                                       Material("Matte", base_color=(0.9, 0.9, 0.9), roughness=0.9)])
    layers = {"opaque": types.SimpleNamespace(element=np.array([0, 0, 0, 0]), material=np.zeros(4, np.int64),
                                              roughness=np.zeros(4, np.float32)),
              "transparent": types.SimpleNamespace(element=np.array([1, 1, 1, 1]), material=np.ones(4, np.int64),
                                                   roughness=np.full(4, 0.9, np.float32))}
    prior = benefit.prior_per_pixel(layers, 3, reflections=[True, True, True], refractions=[False] * 3,
                                    shadows=[False] * 3, materials=materials)
    assert prior[0] == pytest.approx(0.9 * benefit.REFLECTION_CONTRAST, rel=1e-3)
    assert prior[1] == 0.0 and prior[2] == 0.0  # matte: no mirror share; element 2: no pixels
    assert benefit.prior_per_pixel(None, 3, [True] * 3, [True] * 3, [True] * 3, materials).tolist() == [0, 0, 0]


def test_the_item_priors_are_the_prior_of_each_effect_alone_and_sum_to_the_elements_prior():
    """BENEFIT's (n, 3) priors gather the layers once for all three effects: each column is the
    element's prior with that effect alone tagged, exactly; the columns sum to its prior."""
    from phrt.phrt_addon.select import item_benefit
    rng = np.random.default_rng(3)
    materials = shading.MaterialTable([
        Material("Mirror", base_color=(0.9, 0.9, 0.9), metallic=1.0, roughness=0.1),
        Material("Glass", base_color=(1.0, 1.0, 1.0), transmission=1.0, roughness=0.0, ior=1.5),
        Material("Paint", base_color=(0.3, 0.5, 0.2), roughness=0.4)])
    layers = {name: types.SimpleNamespace(element=rng.integers(-1, 6, 500), material=rng.integers(0, 3, 500),
                                          roughness=rng.random(500).astype(np.float32))
              for name in ("opaque", "transparent")}
    flags = {effect: rng.random(5) < 0.6 for effect in ("shadows", "reflections", "refractions")}
    items = item_benefit.priors(layers, 5, flags, materials)
    none = np.zeros(5, bool)
    for column, effect in enumerate(("shadows", "reflections", "refractions")):
        alone = {name: (flags[name] if name == effect else none) for name in flags}
        np.testing.assert_array_equal(items[:, column], benefit.prior_per_pixel(
            layers, 5, alone["reflections"], alone["refractions"], alone["shadows"], materials))
    whole = benefit.prior_per_pixel(layers, 5, flags["reflections"], flags["refractions"], flags["shadows"], materials)
    np.testing.assert_allclose(items.sum(axis=1), whole, rtol=1e-12)
    assert (items > 0).any(axis=0).all()  # every effect has a prior somewhere


def test_running_estimate_replaces_the_prior_then_averages():
    model = benefit.BenefitModel(smoothing=0.5)
    names = ["mirror", "matte"]
    np.testing.assert_allclose(model.benefit(names, [0.4, 0.1]), [0.4, 0.1])
    model.observe(names, [True, False], difference=np.array([60.0, 99.0]), area_px=np.array([100, 100]))
    np.testing.assert_allclose(model.benefit(names, [0.4, 0.1]), [0.6, 0.1])  # the matte was not traced
    model.observe(names, [True, True], difference=np.array([20.0, 0.0]), area_px=np.array([100, 0]))
    np.testing.assert_allclose(model.benefit(names, [0.4, 0.1]), [0.4, 0.1])  # 0.6 + 0.5 (0.2 - 0.6); no pixels
    assert model.observations == {"mirror": 2}
