"""The BENEFIT priors' scale per effect (select/prior_scale.py): fitted on the training paths,
learned from what a replay's traced items measure, and what it changes in the choice."""
import numpy as np
import pytest

from phrt.phrt_addon.select import prior_scale
from phrt.phrt_addon.select.benefit_selection import BenefitSelector
from phrt.phrt_addon.select.prior_scale import PriorScale


def test_the_fitted_scale_applies_from_the_first_frame_per_effect():
    scale = PriorScale()
    raw = np.array([[0.02, 0.1, 0.2]])
    assert scale.apply(raw) == pytest.approx(raw * prior_scale.FITTED[None, :])


def test_the_learned_scale_is_the_median_of_measured_over_prior_once_there_are_enough():
    scale = PriorScale(fitted=np.array([0.1, 1.0, 1.0]))
    raw = np.array([[0.02, 0.1, 0.2], [0.02, 0.1, 0.2]])
    measuring = np.array([[True, False, False], [True, False, False]])
    scale.observe(raw * 0.5, measuring, scale.apply(raw))
    assert scale.scale[0] == pytest.approx(0.1)  # 2 samples: not yet (MIN_SAMPLES), the fitted one
    scale.observe(np.array([[0.02 * 0.3, 0, 0], [0, 0, 0]]), measuring & [[True], [False]], scale.apply(raw))
    assert scale.scale[0] == pytest.approx(0.5)  # median of 0.5, 0.5, 0.3 (of the raw prior)
    assert scale.scale[1:] == pytest.approx([1.0, 1.0])  # unmeasured effects keep theirs
    # The ratios are to the raw prior: the scale in force when chosen (0.5 now) is divided out.
    for _ in range(3):
        scale.observe(raw * 0.4, measuring, scale.apply(raw))
    assert scale.scale[0] == pytest.approx(0.4)  # 0.5, 0.5, 0.3 and six of 0.4


def test_only_full_rate_measurements_of_the_recent_window_count():
    scale = PriorScale(fitted=np.ones(3))
    raw = np.array([[0.02, 0.1, 0.2]])
    one = np.array([[True, False, False]])
    for _ in range(prior_scale.WINDOW):
        scale.observe(raw * 0.2, one, scale.apply(raw))
    assert scale.scale[0] == pytest.approx(0.2)
    for _ in range(prior_scale.WINDOW):
        scale.observe(raw * 0.9, one, scale.apply(raw), full_rate=np.array([[False, True, True]]))
    assert scale.scale[0] == pytest.approx(0.2)  # quarter or half rate: not samples
    for _ in range(prior_scale.WINDOW // 2 + 1):
        scale.observe(raw * 0.9, one, scale.apply(raw))
    assert scale.scale[0] == pytest.approx(0.9)  # the older half forgotten (WINDOW)


def test_a_reflection_measured_with_its_refraction_is_not_a_sample():
    """Glass traced for both: its pixels' change is charged to the refraction and the reflection
    reads 0 (item_benefit.measure); a mirror's reflection is a sample."""
    scale = PriorScale(fitted=np.ones(3))
    raw = np.array([[0.0, 0.1, 0.2], [0.0, 0.1, 0.0]])
    glass_both = np.array([[False, True, True], [False, False, False]])
    for _ in range(prior_scale.MIN_SAMPLES + 2):
        scale.observe(np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.0]]), glass_both, scale.apply(raw))
    assert scale.scale[1] == pytest.approx(1.0)  # the glass's zero reflection never counted
    assert scale.scale[2] == pytest.approx(0.5)
    mirror = np.array([[False, False, False], [False, True, False]])
    for _ in range(prior_scale.MIN_SAMPLES):
        scale.observe(np.array([[0.0, 0.0, 0.0], [0.0, 0.03, 0.0]]), mirror, scale.apply(raw))
    assert scale.scale[1] == pytest.approx(0.3)


def test_the_learned_scale_stays_within_its_range_and_ignores_items_without_a_prior():
    scale = PriorScale(fitted=np.ones(3))
    raw = np.array([[0.02, 0.0, 0.0]] * 4)
    measuring = np.ones((4, 3), bool)
    scale.observe(np.full((4, 3), 5.0), measuring, raw)  # 250x the prior, and no prior at all
    assert scale.scale[0] == pytest.approx(prior_scale.RANGE[1])
    assert scale.scale[1:] == pytest.approx([1.0, 1.0])
    scale.observe(np.zeros((4, 3)), measuring, scale.apply(raw))
    scale.observe(np.zeros((4, 3)), measuring, scale.apply(raw))
    assert scale.scale[0] == pytest.approx(prior_scale.RANGE[0])


def test_a_value_is_weighted_by_the_error_its_effect_removes_per_unit_of_change():
    """The same measured change is worth more LDR-FLIP as a shadow than as a reflection, and less
    as a refraction (prior_scale.EFFECT_WEIGHT, fitted on the training paths)."""
    selector = BenefitSelector()
    selector.observe_time(1.0, 1.0)
    pixels = np.array([[1000.0, 1000.0, 1000.0]])
    priors = np.array([[0.01, 0.01, 0.01]])
    choice = selector.choose(["A"], pixels > 0, pixels, priors, np.ones(1), np.ones((1, 3)), 100.0, 0.0)
    assert choice.value[0] == pytest.approx(10.0 * prior_scale.EFFECT_WEIGHT)
    assert choice.value[0, 0] > choice.value[0, 1] > choice.value[0, 2]


def test_an_untraced_items_estimate_decays_towards_the_scaled_prior():
    selector = BenefitSelector()
    selector.observe_time(1.0, 1.0)
    selector.prior_scale = PriorScale(fitted=np.array([0.5, 1.0, 1.0]), learn=False)
    names, pixels, cost = ["A"], np.array([[100.0, 0.0, 0.0]]), np.array([[1.0, 0.0, 0.0]])
    raw = np.array([[0.02, 0.0, 0.0]])
    priors = selector.priors(names, raw)
    traced = selector.choose(names, pixels > 0, pixels, priors, np.ones(1), cost, 100.0, 0.0)
    selector.observe(names, traced, priors, np.array([[100 * 0.03, 0.0, 0.0]]), pixels)
    assert selector.estimates[("A", "shadows")] == pytest.approx(0.03)
    for _ in range(400):  # no time: not traced, pulled towards the prior as scaled (0.01, not 0.02)
        choice = selector.choose(names, pixels > 0, pixels, selector.priors(names), np.ones(1), cost, 0.0, 0.0)
        selector.observe(names, choice, selector.priors(names))
    assert selector.estimates[("A", "shadows")] == pytest.approx(0.01, rel=1e-3)


def test_without_learning_only_the_fitted_scale_applies():
    scale = PriorScale(fitted=np.ones(3), learn=False)
    scale.observe(np.full((4, 3), 5.0), np.ones((4, 3), bool), np.full((4, 3), 0.02))
    assert scale.scale == pytest.approx([1.0, 1.0, 1.0])


def test_a_scene_whose_shadows_change_little_values_its_untraced_casters_by_that():
    """Casters measured far below the shadow prior (arcade: a footprint most of which the caster
    does not darken): a caster never traced is valued by what the others measured, below a
    mirror's reflection of fewer pixels."""
    selector = BenefitSelector()
    selector.observe_time(1.0, 1.0)
    names = ["CasterA", "CasterB", "CasterC", "CasterD", "Mirror"]
    raw = np.array([[0.02, 0, 0]] * 4 + [[0, 0.4, 0]], float)
    pixels = np.array([[20000, 0, 0]] * 4 + [[0, 3000, 0]], float)
    cost = np.array([[4, 0, 0]] * 4 + [[0, 4, 0]], float)
    eligible = pixels > 0
    priors = selector.priors(names, raw)
    first = selector.choose(names, eligible, pixels, priors, np.ones(5), cost, 100.0, 0.0)
    assert first.chosen[:4, 0].all()  # room for all: every caster is traced and measured
    measured = np.where(first.chosen, pixels * raw * 0.001, 0.0)  # shadows: 1/1000 of the raw prior
    measured[4, 1] = 3000 * 0.4 * prior_scale.FITTED[1]  # the mirror as its prior says
    selector.observe(names, first, priors, measured, pixels)
    assert selector.prior_scale.scale[0] == pytest.approx(0.001)
    # Next frame another caster, never traced, comes into view beside the mirror.
    names2 = ["CasterE", "Mirror"]
    priors2 = selector.priors(names2, raw[3:])
    assert priors2[0, 0] == pytest.approx(0.02 * 0.001)
    choice = selector.choose(names2, pixels[3:] > 0, pixels[3:], priors2, np.ones(2), cost[3:], 4.5, 0.0)
    weight = selector.prior_scale.weight[0]
    assert choice.value[0, 0] == pytest.approx(20000 * 0.02 * 0.001 * weight)  # not the fitted guess's 10x that
    assert choice.value[0, 0] < choice.value[1, 1] / 100
