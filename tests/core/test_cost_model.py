"""Cost model: priors, robust learning, T, both cost modes, and the stiff budget loop.

The closed-loop simulations run the real heuristic against a simulated tracer
whose true cost per ray steps by 10x: the stiff case of the budget loop.
"""
import math

import numpy as np
import pytest

from phrt.phrt_addon.select import heuristic
from phrt.phrt_addon.select import selection_terms
from phrt.phrt_addon.select.cost_model import EFFECTS, MS_PER_RAY_PRIOR, PAPER_MS_PER_COST_PRIOR, STAGE_PRIOR_MS, UNMEASURED_MARGIN, CostModel, FrameStats, normalise_cost_mode
from phrt.phrt_addon.select.robust_estimate import RobustEstimate

TRUE_MS_PER_RAY = np.array([1e-4, 4e-4, 6e-4])  # shadows, reflections, refractions
RAYS_PER_PIXEL_OF_EFFECT = np.array([2.0, 1.0, 3.0])  # 2 lights, 1 reflection, 3 refraction bounces
FRAME_PX = 640 * 480


def _scene(n, seed, mixed_effects):
    rng = np.random.default_rng(seed)
    effects = np.zeros((n, 3), bool)
    effects[np.arange(n), rng.integers(0, 3, n)] = True
    if mixed_effects:
        effects |= rng.random((n, 3)) < 0.3
    return dict(base_area=rng.integers(500, 8000, n), phase=rng.random(n) * 2 * np.pi, effects=effects,
                rays_per_pixel=effects @ RAYS_PER_PIXEL_OF_EFFECT, true_rays_ratio=rng.uniform(0.5, 1.5, n),
                centre=rng.uniform(-0.9, 0.9, (n, 2)), distance=rng.uniform(1, 20, n))


def simulate(cost_mode="measured", frames=60, step_frame=30, step=10.0, n=40, seed=1, mixed_effects=False,
             noise=0.0, outlier_frames=(), budget_ms=150.0):
    """The engine's loop against a simulated tracer; returns per frame
    (predicted trace ms, measured trace ms, T, selected count)."""
    scene = _scene(n, seed, mixed_effects)
    rng = np.random.default_rng(seed + 1)
    model = CostModel()
    settings = selection_terms.SelectionSettings(budget_ms=budget_ms, cost_mode=cost_mode)
    names = [f"element{i}" for i in range(n)]
    previous = None
    history = []
    for frame in range(frames):
        area = (scene["base_area"] * (1 + 0.3 * np.sin(frame / 7 + scene["phase"]))).astype(np.int64)
        elements = selection_terms.FrameElements(
            names=names, area_px=area, frame_px=FRAME_PX, centre_ndc=scene["centre"], distance=scene["distance"],
            shadows=scene["effects"][:, 0], reflections=scene["effects"][:, 1],
            refractions=scene["effects"][:, 2], rays_per_pixel=scene["rays_per_pixel"])
        result = heuristic.select(elements, previous, settings, model, frame=frame)
        rays = area * scene["rays_per_pixel"] * scene["true_rays_ratio"] * result.selected
        split = scene["effects"] * RAYS_PER_PIXEL_OF_EFFECT / np.maximum(scene["rays_per_pixel"][:, None], 1e-12)
        effect_rays = (rays[:, None] * split).sum(axis=0)
        effect_ms = effect_rays * TRUE_MS_PER_RAY * (step if frame >= step_frame else 1.0)
        trace_ms = float(effect_ms.sum())
        if noise:
            trace_ms *= math.exp(rng.normal(0.0, noise))
        if frame in outlier_frames:
            trace_ms *= 8.0
        model.observe(FrameStats(raster_ms=30.0, select_ms=1.0, composite_ms=4.0, trace_ms=trace_ms,
                                 effect_ms=dict(zip(EFFECTS, effect_ms)), effect_rays=dict(zip(EFFECTS, effect_rays)),
                                 element_rays=rays), result)
        history.append((result.predicted_trace_ms, trace_ms, result.time_left_ms, int(result.selected.sum())))
        previous = result
    return history


def relative_errors(history):
    return np.array([(predicted - measured) / measured if measured > 0 else 0.0
                     for predicted, measured, _, _ in history])


def sign_flips(errors, ignore_below):
    """Changes of sign of the error, ignoring errors smaller than ``ignore_below``."""
    signs = [np.sign(error) for error in errors if abs(error) > ignore_below]
    return sum(1 for before, after in zip(signs, signs[1:]) if before != after)


# -- RobustEstimate ----------------------------------------------------------

def test_estimate_uses_prior_until_first_measurement_then_replaces_it():
    estimate = RobustEstimate(5.0)
    assert estimate.value == 5.0
    estimate.update(40.0)
    assert estimate.value == pytest.approx(40.0)


def test_estimate_votes_out_a_slow_first_frame_during_cold_start():
    estimate = RobustEstimate(50.0)
    for measured in (420.0, 60.0, 60.0):  # first frame JIT-slow, then steady
        estimate.update(measured)
    assert estimate.value == pytest.approx(60.0)


def test_estimate_ignores_a_single_outlier_once_warm():
    estimate = RobustEstimate(1.0)
    for _ in range(8):
        estimate.update(10.0)
    estimate.update(100.0)
    assert estimate.value == pytest.approx(10.0)
    estimate.update(10.0)
    assert estimate.value == pytest.approx(10.0)


def test_estimate_follows_a_step_down_after_confirm_frames_without_overshoot():
    estimate = RobustEstimate(1.0, confirm=3)
    for _ in range(8):
        estimate.update(20.0)
    values = []
    for _ in range(6):
        estimate.update(2.0)
        values.append(estimate.value)
    assert values[:2] == [pytest.approx(20.0)] * 2
    assert values[2:] == [pytest.approx(2.0)] * 4


def test_estimate_follows_a_step_up_after_two_frames_so_at_most_two_frames_run_over():
    estimate = RobustEstimate(1.0, confirm=3)
    for _ in range(8):
        estimate.update(2.0)
    values = []
    for _ in range(6):
        estimate.update(20.0)
        values.append(estimate.value)
    assert values[:1] == [pytest.approx(2.0)]
    assert values[1:] == [pytest.approx(20.0)] * 5


def test_estimate_needs_consecutive_outliers_on_one_side():
    estimate = RobustEstimate(1.0, confirm=3)
    for _ in range(8):
        estimate.update(10.0)
    for measured in (100.0, 1.0, 100.0, 1.0, 100.0):  # alternating outliers are not a step
        estimate.update(measured)
        assert estimate.value == pytest.approx(10.0)


def test_estimate_smooths_noise_inside_the_gate():
    estimate = RobustEstimate(1.0, smoothing=0.5)
    for _ in range(6):
        estimate.update(10.0)
    estimate.update(11.0)
    assert estimate.value == pytest.approx(10.0 * math.sqrt(1.1))  # half way in the log domain


@pytest.mark.parametrize("garbage", [float("nan"), float("inf"), -3.0, None, "fast"])
def test_estimate_ignores_unusable_measurements(garbage):
    estimate = RobustEstimate(7.0)
    assert estimate.update(garbage) is False
    assert estimate.value == 7.0


def test_estimate_rejects_a_non_positive_prior():
    with pytest.raises(ValueError):
        RobustEstimate(0.0)


# -- T and stage times -------------------------------------------------------

def test_time_left_from_priors_is_budget_minus_predicted_stages():
    model = CostModel()
    assert model.time_left(150.0) == pytest.approx(150.0 - sum(STAGE_PRIOR_MS.values()))


def test_time_left_learns_the_measured_stage_times():
    model = CostModel()
    model.observe(FrameStats(raster_ms=20.0, select_ms=0.5, composite_ms=3.5))
    assert model.stage_ms() == pytest.approx({"raster": 20.0, "select": 0.5, "composite": 3.5})
    assert model.time_left(100.0) == pytest.approx(76.0)


def test_time_left_after_a_measured_raster_half_uses_the_measurement():
    """The selection runs after the G-buffer: the time left is what this frame's raster half
    left, not what the model predicted it would take (a slow raster frame leaves less)."""
    model = CostModel()
    model.observe(FrameStats(raster_ms=20.0, select_ms=0.5, composite_ms=3.5))
    assert model.time_left(100.0, raster_ms=50.0) == pytest.approx(46.0)
    assert model.time_left(100.0, raster_ms=0.0) == pytest.approx(96.0)
    assert model.time_left(100.0, raster_ms=200.0) == 0.0
    # A measurement that is not a number falls back on the prediction; +inf leaves nothing.
    assert model.time_left(100.0, raster_ms=float("nan")) == pytest.approx(76.0)
    assert model.time_left(100.0, raster_ms=float("inf")) == 0.0


@pytest.mark.parametrize("budget", [0.0, 10.0, -5.0, float("nan")])
def test_time_left_is_never_negative(budget):
    assert CostModel().time_left(budget) == 0.0


def test_time_left_is_finite_for_an_infinite_budget():
    assert math.isfinite(CostModel().time_left(float("inf")))


def test_a_stage_measured_at_zero_ms_is_learned_as_nearly_zero():
    model = CostModel()
    model.observe(FrameStats(composite_ms=0.0))
    assert model.stage_ms()["composite"] < 0.01


@pytest.mark.parametrize("spelling, expected", [("PAPER", "paper"), ("paper", "paper"), ("MEASURED", "measured"),
                                                ("Measured", "measured")])
def test_cost_mode_accepts_both_cases(spelling, expected):
    assert normalise_cost_mode(spelling) == expected


def test_unknown_cost_mode_is_refused():
    with pytest.raises(ValueError, match="cost_mode"):
        normalise_cost_mode("guess")


# -- element predictions -----------------------------------------------------

def _one_element_frame(**overrides):
    fields = dict(names=["glass"], area_px=np.array([1000]), frame_px=FRAME_PX, reflections=np.array([True]),
                  rays_per_pixel=np.array([2.0]), rt_cost=np.array([1.0]))
    fields.update(overrides)
    return selection_terms.FrameElements(**fields)


def test_measured_prediction_is_pixels_times_rays_times_cost_per_ray_times_q():
    elements = _one_element_frame(rt_cost=np.array([3.0]))
    model = CostModel()
    predicted = model.predict_element_ms(elements, np.array([0.5]), "MEASURED")
    # Never measured: the prior with the margin of a first guess.
    assert predicted[0] == pytest.approx(1000 * 2.0 * MS_PER_RAY_PRIOR["reflections"] * 3.0 * UNMEASURED_MARGIN)
    model.observe(FrameStats(trace_ms=1.0, effect_ms={"reflections": 1.0}, effect_rays={"reflections": 2500.0}))
    predicted = model.predict_element_ms(elements, np.array([0.5]), "MEASURED")
    assert predicted[0] == pytest.approx(1000 * 2.0 * (1.0 / 2500.0) * 3.0)


def test_paper_prediction_is_the_fitted_factor_times_c():
    predicted = CostModel().predict_element_ms(_one_element_frame(), np.array([0.5]), "paper")
    assert predicted[0] == pytest.approx(PAPER_MS_PER_COST_PRIOR * 0.5)


def test_invisible_element_is_predicted_free_in_measured_mode():
    predicted = CostModel().predict_element_ms(_one_element_frame(area_px=np.array([0])), np.array([0.0]), "measured")
    assert predicted[0] == 0.0


def test_per_effect_cost_per_ray_is_learned_with_overhead_shared():
    elements = _one_element_frame()
    result = heuristic.select(elements, None, selection_terms.SelectionSettings(budget_ms=1e6), CostModel())
    model = CostModel()
    # 10 ms measured for the whole trace; effect timers say 6 + 2 (2 ms overhead).
    model.observe(FrameStats(trace_ms=10.0, effect_ms={"shadows": 6.0, "reflections": 2.0},
                             effect_rays={"shadows": 30000, "reflections": 10000}), result)
    assert model.ms_per_ray()["shadows"] == pytest.approx(10.0 * 6 / 8 / 30000)
    assert model.ms_per_ray()["reflections"] == pytest.approx(10.0 * 2 / 8 / 10000)
    assert model.ms_per_ray()["refractions"] == MS_PER_RAY_PRIOR["refractions"]


def test_the_fixed_cost_of_tracing_is_learned_apart_from_the_rays_and_charged_once():
    """Reading the layers back and updating the scene cost the same whatever is traced: measured
    apart (trace_overhead_ms), they stay out of the cost per ray, and a selection is charged them
    once, so an element fits only if it fits beside them."""
    model = CostModel()
    assert model.trace_overhead_ms() == 0.0  # never measured: not charged
    for rays in (10000, 50000, 20000, 10000, 30000, 40000):
        model.observe(FrameStats(raster_ms=20.0, select_ms=1.0, composite_ms=5.0, trace_ms=30.0 + rays * 1e-3,
                                 effect_ms={"reflections": rays * 1e-3}, effect_rays={"reflections": rays},
                                 trace_overhead_ms=30.0))
    assert model.trace_overhead_ms() == pytest.approx(30.0)
    assert model.ms_per_ray()["reflections"] == pytest.approx(1e-3)
    # T = 100 - 26 = 74 ms; the element costs 1000 px * 2 rays * 1e-3 * Q: 2 ms * Q.
    settings = selection_terms.SelectionSettings(budget_ms=100.0)
    fits = heuristic.select(_one_element_frame(rt_cost=np.array([20.0])), None, settings, model)  # 40 ms
    assert fits.selected[0] and fits.predicted_trace_ms == pytest.approx(70.0)
    too_much = heuristic.select(_one_element_frame(rt_cost=np.array([25.0])), None, settings, model)  # 50 ms
    assert not too_much.selected[0] and too_much.predicted_trace_ms == 0.0
    assert too_much.time_left_ms == pytest.approx(74.0)  # T itself is the paper's
    assert model.state()["trace_overhead_ms"] == pytest.approx(30.0)
    for garbage in (float("nan"), -5.0, float("inf"), "x"):  # ignored, the rest of the frame still learned
        model.observe(FrameStats(trace_ms=40.0, effect_ms={"reflections": 10.0}, effect_rays={"reflections": 1e4},
                                 trace_overhead_ms=garbage))
    assert model.trace_overhead_ms() == pytest.approx(30.0)


def test_element_rays_teach_the_element_its_own_rays_per_pixel():
    elements = _one_element_frame()
    model = CostModel()
    result = heuristic.select(elements, None, selection_terms.SelectionSettings(budget_ms=1e6), model)
    # The engine guessed 2 rays per pixel; the tracer cast 3 per pixel.
    model.observe(FrameStats(trace_ms=3000 * 1e-3, effect_rays={"reflections": 3000},
                             effect_ms={"reflections": 3.0}, element_rays=np.array([3000.0])), result)
    predicted = model.predict_element_ms(elements, result.C, "measured")
    assert predicted[0] == pytest.approx(3.0)  # 1000 px * 3 rays * 1e-3 ms


def test_element_rays_of_the_wrong_length_are_refused():
    elements = _one_element_frame()
    result = heuristic.select(elements, None, selection_terms.SelectionSettings(budget_ms=1e6))
    with pytest.raises(ValueError, match="element_rays"):
        CostModel().observe(FrameStats(trace_ms=1.0, element_rays=np.ones(3)), result)


def test_garbage_measurements_leave_every_prediction_finite():
    elements = _one_element_frame()
    model = CostModel()
    result = heuristic.select(elements, None, selection_terms.SelectionSettings(budget_ms=1e6), model)
    model.observe(FrameStats(raster_ms=float("nan"), select_ms=-1.0, composite_ms=float("inf"),
                             trace_ms=float("nan"), effect_ms={"shadows": float("inf")},
                             effect_rays={"shadows": -5}, element_rays=np.array([float("nan")])), result)
    assert all(math.isfinite(value) for value in model.state().values())
    assert np.all(np.isfinite(model.predict_element_ms(elements, result.C, "measured")))


# -- the stiff budget loop ---------------------------------------------------

@pytest.mark.parametrize("step", [10.0, 0.1])
def test_measured_mode_recovers_from_a_10x_cost_step_within_10_frames_without_oscillating(step):
    history = simulate("measured", frames=60, step_frame=30, step=step)
    errors = relative_errors(history)
    # Cold start: the priors are off, the first frame's measurement fixes them.
    assert abs(errors[0]) > 0.1
    assert np.all(np.abs(errors[10:30]) < 0.10)
    # The step: predicted trace time back within 10% of measured within 10 frames.
    assert abs(errors[30]) > 0.5
    assert np.all(np.abs(errors[40:]) < 0.10)
    # Exactly after `confirm` (3) frames here, as the model is exactly specified.
    assert np.all(np.abs(errors[33:]) < 1e-6)
    # The error changes sign at most twice (float rounding, under 1e-6, is zero).
    assert sign_flips(errors[30:], ignore_below=1e-6) <= 2
    assert sign_flips(errors, ignore_below=1e-6) <= 2


def test_measured_mode_keeps_the_frame_within_budget_after_the_step():
    history = simulate("measured", frames=50, step_frame=20, step=10.0)
    for predicted, measured, time_left, selected in history[23:]:
        assert measured <= time_left * 1.000001
        assert selected > 0


def test_measured_mode_recovers_with_mixed_effects_noise_and_outliers():
    history = simulate("measured", frames=70, step_frame=30, step=10.0, mixed_effects=True, noise=0.03,
                       outlier_frames=(15, 50))
    errors = relative_errors(history)
    steady = [frame for frame in list(range(10, 30)) + list(range(40, 70)) if frame not in (15, 50)]
    assert np.all(np.abs(errors[steady]) < 0.10)
    # The frame after an outlier is predicted as well as before it.
    assert abs(errors[16]) < 0.10 and abs(errors[51]) < 0.10
    # No oscillation beyond the measurement noise (3%).
    assert sign_flips(errors[30:], ignore_below=0.10) <= 2


def test_paper_mode_factor_recovers_from_a_10x_step_on_a_fixed_selection():
    """Open loop (the same selection every frame): the paper's factor follows the step."""
    elements = selection_terms.FrameElements(names=["a", "b"], area_px=np.array([5000, 3000]), frame_px=FRAME_PX,
                                       centre_ndc=np.zeros((2, 2)), distance=np.array([2.0, 4.0]),
                                       reflections=np.array([True, True]))
    settings = selection_terms.SelectionSettings(budget_ms=1e6, cost_mode="PAPER")
    model = CostModel()
    errors = []
    for frame in range(30):
        result = heuristic.select(elements, None, settings, model)
        measured = 12.0 * (10.0 if frame >= 10 else 1.0)
        errors.append((result.predicted_trace_ms - measured) / measured)
        model.observe(FrameStats(trace_ms=measured), result)
    errors = np.array(errors)
    assert np.all(np.abs(errors[1:10]) < 1e-9)
    assert abs(errors[10]) > 0.5
    assert np.all(np.abs(errors[20:]) < 0.10)
    assert sign_flips(errors, ignore_below=1e-6) <= 2


def test_a_fixed_overhead_learned_too_high_is_revised_after_frames_that_could_have_traced():
    """A fixed trace overhead measured once at 40 ms (a hiccup) and never traced again since (it
    leaves no time): after STALE_FRAMES frames that wanted to trace it is halved, then after twice
    as many, and so on; frames that could not trace (nothing in view) do not count; the next
    measurement is a cold start (it replaces the revised value, not averaged with the old)."""
    from phrt.phrt_addon.select.cost_model import STALE_DISCOUNT, STALE_FRAMES, STALE_MAX_FRAMES
    model = CostModel()
    for _ in range(2):  # measured twice (a value measured once is revised faster: below)
        model.observe(FrameStats(trace_ms=45.0, trace_overhead_ms=40.0, trace_wanted=True))
    assert model.trace_overhead_ms() == pytest.approx(40.0)
    for _ in range(3 * STALE_FRAMES):
        model.observe(FrameStats(raster_ms=30.0, trace_wanted=False))  # nothing to trace: no revision
    assert model.trace_overhead_ms() == pytest.approx(40.0)
    seen = []
    for _ in range(8 * STALE_MAX_FRAMES):
        model.observe(FrameStats(raster_ms=30.0, trace_wanted=True))
        seen.append(model.trace_overhead_ms())
    before = [40.0] + seen[:-1]
    drops = [frame + 1 for frame, (now, then) in enumerate(zip(seen, before)) if now < then]
    assert all(now == pytest.approx(then / STALE_DISCOUNT) for now, then in zip(seen, before) if now < then)
    gaps, period = list(np.diff([0] + drops)), STALE_FRAMES
    while period < STALE_MAX_FRAMES:  # STALE_FRAMES, then twice as many each time ...
        assert gaps.pop(0) == period
        period *= 2
    assert gaps and set(gaps) == {STALE_MAX_FRAMES}  # ... up to STALE_MAX_FRAMES
    model.observe(FrameStats(trace_ms=5.0, trace_overhead_ms=3.0, trace_wanted=True))
    assert model.trace_overhead_ms() == pytest.approx(3.0)


def test_a_traced_frame_resets_the_overhead_idle_count():
    from phrt.phrt_addon.select.cost_model import STALE_FRAMES
    model = CostModel()
    model.observe(FrameStats(trace_ms=12.0, trace_overhead_ms=10.0, trace_wanted=True))
    for _ in range(5):
        for _ in range(STALE_FRAMES - 1):
            model.observe(FrameStats(raster_ms=30.0, trace_wanted=True))
            assert model.trace_overhead_ms() == pytest.approx(10.0)  # not revised: the count restarted
        model.observe(FrameStats(trace_ms=12.0, trace_overhead_ms=10.0, trace_wanted=True))


def test_robust_estimate_revise_divides_and_starts_over():
    estimate = RobustEstimate(1.0)
    for value in (8.0, 8.0, 8.0, 8.0, 8.0, 8.0):
        estimate.update(value)
    estimate.revise(4.0)
    assert estimate.value == pytest.approx(2.0)
    estimate.update(100.0)  # a cold start: taken at once (outside the gate it would be ignored)
    assert estimate.value == pytest.approx(100.0)


def test_an_overhead_measured_once_is_revised_every_stale_period():
    """A first, cold trace (the tracer's imports) measured once and pricing tracing out: halved every
    STALE_FRAMES frames, not ever more slowly, so tracing resumes within a few periods."""
    from phrt.phrt_addon.select.cost_model import STALE_DISCOUNT, STALE_FRAMES
    model = CostModel()
    model.observe(FrameStats(trace_ms=60.0, trace_overhead_ms=54.0, trace_wanted=True))
    for revision in range(1, 5):
        for _ in range(STALE_FRAMES):
            model.observe(FrameStats(raster_ms=30.0, trace_wanted=True))
        assert model.trace_overhead_ms() == pytest.approx(54.0 / STALE_DISCOUNT ** revision)
