"""The BENEFIT selection (select/benefit_selection.py): value, switching cost, exploration, the
margin, and a frame rendered with it (items traced per effect, rows with their estimates)."""
import dataclasses

import numpy as np
import pytest

from phrt.phrt_addon.select import benefit_selection
from phrt.phrt_addon.select.benefit_selection import BenefitSelector
from phrt.phrt_addon.runs import summary as run_summary
from phrt.phrt_addon.scene.snapshot import Element

from test_frame import mirror_scene, render


def choose(selector, names, pixels, priors, cost_ms, time_left, priority=None, exact=True):
    """One frame's choice; ``exact``: the frame before was predicted exactly (no margin)."""
    if exact:
        selector.observe_time(1.0, 1.0)
    n = len(names)
    pixels = np.asarray(pixels, float).reshape(n, 3)
    eligible = pixels > 0
    return selector.choose(names, eligible, pixels, np.asarray(priors, float).reshape(n, 3),
                           np.ones(n) if priority is None else np.asarray(priority, float),
                           np.asarray(cost_ms, float).reshape(n, 3), time_left, 0.0)


def settle_margin(selector):
    selector.observe_time(1.0, 1.0)  # one exact prediction: no margin


def test_value_is_pixels_changed_times_difference_so_a_small_caster_with_a_large_footprint_wins():
    selector = BenefitSelector()
    settle_margin(selector)
    # Caster: 50 own pixels, but its shadow covers 4000 receiver pixels; the matte's reflection:
    # 2000 pixels that barely change.  Only one fits.
    pixels = [[4000, 0, 0], [0, 2000, 0]]
    priors = [[0.05, 0, 0], [0, 0.01, 0]]
    choice = choose(selector, ["Caster", "Matte"], pixels, priors, [[8, 0, 0], [0, 8, 0]], 10.0)
    assert choice.chosen.tolist() == [[True, False, False], [False, False, False]]


def test_priority_k_multiplies_value():
    selector = BenefitSelector()
    settle_margin(selector)
    pixels, priors, cost = [[0, 100, 0], [0, 100, 0]], [[0, 0.2, 0], [0, 0.1, 0]], [[0, 8, 0], [0, 8, 0]]
    assert choose(selector, ["A", "B"], pixels, priors, cost, 10.0).chosen[0, 1]
    other = BenefitSelector()
    settle_margin(other)
    assert choose(other, ["A", "B"], pixels, priors, cost, 10.0, priority=[1.0, 3.0]).chosen[1, 1]


def test_an_item_alternating_around_its_rival_does_not_flip_every_frame_but_a_better_one_wins():
    selector = BenefitSelector()
    settle_margin(selector)
    names, pixels, cost = ["A", "B"], [[0, 100, 0], [0, 100, 0]], [[0, 8, 0], [0, 8, 0]]
    priors = np.array([[0, 0.1, 0], [0, 0.1, 0]], float)
    flips, state = 0, None
    for frame in range(30):
        choice = choose(selector, names, pixels, priors, cost, 10.0)
        chosen = int(np.argmax(choice.chosen[:, 1]))
        flips += state is not None and chosen != state
        state = chosen
        # Each frame, the traced item measures 5% above or below its rival's estimate.
        measured = np.zeros((2, 3))
        measured[chosen, 1] = 100 * 0.1 * (1.05 if frame % 2 else 0.95)
        selector.observe(names, choice, priors, measured, np.asarray(pixels, float))
    assert flips <= 2, flips  # exploration may try the other once; no ping-pong
    # Now B is measured twice as good as A whenever traced: it is taken within 3 frames.
    selector.estimates[("B", "reflections")] = 0.2
    taken = []
    for _ in range(3):
        choice = choose(selector, names, pixels, priors, cost, 10.0)
        taken.append(bool(choice.chosen[1, 1]))
    assert any(taken)


def test_a_never_traced_item_is_tried_within_the_exploration_bound_when_the_budget_allows():
    """The exploration bonus competes for the time the traced items leave: a never-measured
    item (its prior says worthless) does not evict a traced one (a pop for a guess), and once
    there is room beside it, the item that waited EXPLORE_FRAMES wins that room over a rival
    the estimates prefer."""
    selector = BenefitSelector()
    settle_margin(selector)
    names = ["Known", "Rival", "New"]
    pixels, cost = [[0, 100, 0]] * 3, [[0, 8, 0], [0, 6, 0], [0, 6, 0]]
    priors = np.array([[0, 0.5, 0], [0, 0.4, 0], [0, 0.001, 0]], float)
    selector.estimates[("Known", "reflections")] = 0.5
    selector.estimates[("Rival", "reflections")] = 0.4
    for frame in range(benefit_selection.EXPLORE_FRAMES + 2):  # the time for Known alone
        choice = choose(selector, names, pixels, priors, cost, 10.0)
        assert choice.chosen[:, 1].tolist() == [True, False, False], (frame, choice.chosen)
        selector.observe(names, choice, priors)
    added = None
    for frame in range(benefit_selection.STEADY_FRAMES):  # room for one more beside Known, lasting
        choice = choose(selector, names, pixels, priors, cost, 18.0)
        assert choice.chosen[0, 1], (frame, choice.chosen)
        if choice.chosen[1:, 1].any():
            added = choice.chosen[1:, 1].tolist()
            break
        selector.observe(names, choice, priors)
    assert added == [False, True], added


def test_one_outlier_does_not_hold_the_margin():
    """Below MARGIN_MIN_SAMPLES informed frames the margin is their median: one frame measured
    15 ms over its prediction (a first frame, a hiccup) does not shut the time left for 20 frames."""
    selector = BenefitSelector()
    names, pixels, priors, cost = ["A"], [[0, 100, 0]], [[0, 0.5, 0]], [[0, 4, 0]]
    for error in (15.0, 0.0, 0.5):
        choose(selector, names, pixels, priors, cost, 10.0, exact=False)
        selector.observe_time(4.0, 4.0 + error)
    assert selector.margin_ms(30.0) == pytest.approx(0.5)
    assert choose(selector, names, pixels, priors, cost, 10.0, exact=False).chosen.any()


def test_the_margin_follows_the_predictions_recent_errors_and_ages_by_frames():
    selector = BenefitSelector()
    assert selector.margin_ms(30.0) == 0.0  # nothing measured: no margin
    names, pixels, priors, cost = ["A"], [[0, 100, 0]], [[0, 0.5, 0]], [[0, 6, 0]]
    for error in [0.0] * 10 + [8.0] * 4:  # four frames measured 8 ms above their prediction
        choose(selector, names, pixels, priors, cost, 10.0, exact=False)
        selector.observe_time(6.0, 6.0 + error)
    assert selector.margin_ms(40.0) >= 8.0
    assert selector.margin_ms(10.0) == 5.0  # never more than half the time left
    # 6 ms predicted no longer fits 10 ms once its errors are known; a few exact frames later the
    # errors are still in the window.
    for _ in range(3):
        assert not choose(selector, names, pixels, priors, cost, 10.0, exact=False).chosen.any()
        selector.observe_time(6.0, 6.0)
    # Frames that trace nothing age the errors out: the item is tried again (a margin that only
    # traced frames could lower would keep a tight budget from ever tracing again).
    tried = False
    for _ in range(benefit_selection.MARGIN_FRAMES + 1):
        tried |= bool(choose(selector, names, pixels, priors, cost, 10.0, exact=False).chosen.any())
    assert tried


def benefit_mirror_scene(block_shadows):
    """test_frame's mirror scene under BENEFIT, its matte block tagged for reflections too (tracing
    that reflection changes nearly nothing)."""
    snapshot = mirror_scene("HYBRID")
    snapshot.settings.selection = "BENEFIT"
    snapshot.elements[1] = Element("Block", "Block", priority=1.0, shadows=block_shadows, reflections=True,
                                   refractions=False)
    return snapshot


def test_a_frame_with_benefit_traces_items_and_logs_their_estimates():
    result, _, renderer = render(benefit_mirror_scene(block_shadows=True))
    rows = {row["element"]: row for row in result.selection_rows}
    assert rows["Mirror"]["selected"] == 1 and "reflections" in rows["Mirror"]["effects"]
    assert all(np.isfinite(row["predicted_ms"]) and np.isfinite(row["benefit"]) for row in rows.values())
    selector = renderer.benefit_selector
    # The mirror's reflection was traced and measured: its estimate is the red wall it shows.
    assert selector.observations.get(("Mirror", "reflections"), 0) == 1
    assert selector.estimates[("Mirror", "reflections")] > 0.05
    # Rays for the chosen items only: the block's shadow alone when its reflection is left out.
    effects = result.selection.effects
    assert effects["shadows"][1] == (result.stats["shadow_rays"] > 0)
    assert effects["reflections"][1] or result.stats["reflection_rays"] > 0


def test_q_weighs_the_choice_not_the_time_the_frame_is_planned_with():
    """A designer's Q of 4 on the block: the choice takes its value per ms as a quarter (its logged
    estimate, the value the knapsack used, is divided by Q), but its predicted ms stay what tracing
    it takes, so the frame's predicted trace time (what the budget is kept with) is unchanged."""
    rows = {}
    for q in (1.0, 4.0):
        snapshot = benefit_mirror_scene(block_shadows=True)
        snapshot.elements[1].rt_cost = q
        result, _, _ = render(snapshot)
        rows[q] = {row["element"]: row for row in result.selection_rows}
        assert rows[q]["Block"]["selected"] == 1  # the whole frame's time is there: both are bought
    assert rows[4.0]["Block"]["predicted_ms"] == pytest.approx(rows[1.0]["Block"]["predicted_ms"], rel=1e-9)
    assert rows[4.0]["Block"]["benefit"] == pytest.approx(rows[1.0]["Block"]["benefit"] / 4.0, rel=1e-9)
    assert rows[4.0]["Mirror"]["benefit"] == pytest.approx(rows[1.0]["Mirror"]["benefit"], rel=1e-9)


def test_the_mirror_outranks_the_matte_reflection_from_the_first_frame():
    result, _, _ = render(benefit_mirror_scene(block_shadows=False))
    value = result.selection.benefit_estimate
    per_pixel_mirror = value[0] / max(result.selection.elements.area_px[0], 1)
    per_pixel_block = value[1] / max(result.selection.elements.area_px[1], 1)
    assert per_pixel_mirror > 5 * per_pixel_block


def test_with_tiers_an_item_that_does_not_fit_at_full_rate_is_bought_at_a_lower_one(monkeypatch):
    # Full costs 10 ms; a new item is charged (1 + ADD_SLACK) x each rate's share of it: with the
    # slack at 0.25 (a value that tells the charge from the cost) full 12.5, half 11.25, quarter 8.75.
    monkeypatch.setattr(benefit_selection, "ADD_SLACK", 0.25)
    def choice_at(time_left, tiers=True):
        selector = BenefitSelector()
        selector.observe_time(1.0, 1.0)
        return selector.choose(["Mirror"], np.array([[False, True, False]]), np.array([[0, 500, 0]]),
                               np.array([[0, 0.4, 0]]), np.ones(1), np.array([[0, 10.0, 0]]), time_left, 0.0,
                               tiers=tiers)
    charged = {rate: 10.0 * share * (1.0 + benefit_selection.ADD_SLACK)
               for rate, share in benefit_selection.TIER_COST.items()}
    assert charged[0.25] < charged[0.5] < charged[1.0]
    assert not choice_at(charged[0.25] - 0.5).chosen.any()
    quarter = choice_at((charged[0.25] + charged[0.5]) / 2)
    assert quarter.rate[0, 1] == 0.25 and quarter.rates["reflections"][0] == 0.25
    assert quarter.chosen_cost_ms[0, 1] == pytest.approx(10.0 * benefit_selection.TIER_COST[0.25])
    between = (charged[0.5] + charged[1.0]) / 2
    assert choice_at(between).rate[0, 1] == 0.5
    assert choice_at(charged[1.0] + 0.5).rate[0, 1] == 1.0
    assert not choice_at(between, tiers=False).chosen.any()  # all or nothing: nothing


def test_a_frame_with_tiers_traces_at_the_chosen_rate_and_writes_the_rate_pass():
    snapshot = mirror_scene("HYBRID")
    snapshot.settings.selection = "BENEFIT"
    snapshot.settings.quality_tiers = True
    result, _, renderer = render(snapshot)
    rate = result.passes.rate
    assert rate.shape == result.passes.depth.shape and np.isfinite(rate).all()
    chosen = result.selection.effects
    assert chosen["reflections"][0]  # the mirror, all the time there is: at full rate
    assert set(np.unique(rate)) <= {0.0, 0.25, 0.5, 1.0} and (rate == 1.0).any()
    # The mirror (element index 0: pass value 1) was traced at full rate on every pixel it traced.
    assert rate[(result.passes.element == 1) & (rate > 0)].min() == 1.0


def test_the_material_priors_are_computed_only_when_an_item_has_none_or_they_are_old():
    selector = BenefitSelector()
    visible = np.array([True, False])
    assert selector.needs_priors(["A", "B"], visible)
    priors = selector.priors(["A", "B"], np.array([[0.0, 0.3, 0.0], [0.02, 0.0, 0.0]]))
    scale = selector.prior_scale.scale  # the materials' guess, scaled per effect
    assert priors[0, 1] == pytest.approx(0.3 * scale[1])
    selector.frames += 1
    assert not selector.needs_priors(["A", "B"], visible)
    assert selector.priors(["A", "B"])[1, 0] == pytest.approx(0.02 * scale[0])  # cached
    assert selector.needs_priors(["A", "C"], np.array([False, True]))  # C has none
    selector.frames += benefit_selection.PRIOR_EVERY
    assert selector.needs_priors(["A", "B"], visible)  # old
    assert not selector.needs_priors(["A", "B"], np.array([False, False]))  # nothing visible: nothing to read


def test_an_effect_never_measured_is_probed_with_one_item():
    """The first frame of an effect traces its most valuable item per predicted ms alone: the
    costs of the others are guesses until that measurement (a replay's start would otherwise
    select everything at the priors' price and drop most of it a frame later: popping)."""
    selector = BenefitSelector()
    names = ["A", "B", "C"]
    pixels = np.array([[0, 100, 0], [0, 300, 0], [0, 200, 0]], float)
    priors = np.full((3, 3), 0.5)
    cost = np.array([[0, 1.0, 0], [0, 2.0, 0], [0, 4.0, 0]], float)
    args = (names, pixels > 0, pixels, priors, np.ones(3), cost, 100.0, 0.0)
    probe = selector.choose(*args, unmeasured=np.array([True, True, True]))
    assert probe.chosen[:, 1].tolist() == [False, True, False]  # B: 150 per ms, A 50, C 25
    assert selector.choose(*args, unmeasured=np.zeros(3, bool)).chosen[:, 1].all()


def test_the_share_a_reduced_rate_keeps_is_learned_per_effect():
    """A mirror measured at full rate, then at quarter rate keeping 40% of that change: the
    quarter rate's share of a reflection moves from its prior towards 0.4, and the full-rate
    estimate is what the quarter-rate measurement implies under the learned share."""
    selector = BenefitSelector()
    names, pixels, priors, cost = ["M"], np.array([[0, 100, 0]], float), np.full((1, 3), 0.5), [[0, 4, 0]]
    full = choose(selector, names, pixels, priors, cost, 100.0)
    selector.observe(names, full, priors, np.array([[0, 50.0, 0]]), pixels)  # 0.5 a pixel at full rate
    before = selector.keep("reflections", 0.25)
    quarter = dataclasses.replace(full, rate=np.array([[0, 0.25, 0]]))
    selector.observe(names, quarter, priors, np.array([[0, 20.0, 0]]), pixels)  # 0.2: a 40% share
    after = selector.keep("reflections", 0.25)
    assert before == benefit_selection.TIER_KEEP[0.25]
    assert 0.4 < after < before
    assert selector.keep("refractions", 0.25) == before  # per effect


def test_the_priors_read_back_is_not_taken_from_the_time_left_twice(monkeypatch):
    """A frame that reads the layers for the material priors before the selection: the time left
    is measured after the raster half without that read-back (the trace stage skips its own, and
    its fixed overhead, charged against T, holds it); it was charged twice every PRIOR_EVERY frames."""
    from phrt.phrt_addon import frame as frame_module
    seen = []
    select = frame_module.heuristic.select

    def spy(*args, **kwargs):
        seen.append(kwargs["raster_ms"])
        return select(*args, **kwargs)

    monkeypatch.setattr(frame_module.heuristic, "select", spy)
    result, _, _ = render(benefit_mirror_scene(block_shadows=True))
    stats = result.stats
    assert stats["readback_ms"] > 0  # the first frame computes its priors from the layers
    assert seen[0] == pytest.approx(max(stats["raster_ms"] - stats["readback_ms"], 0.0), abs=1e-6)


def test_a_traced_item_holds_through_the_time_lefts_noise_and_an_added_one_needs_room_to_spare(monkeypatch):
    """The band in time (HOLD, ADD_SLACK): an item costing 10 ms is kept while the time left swings
    around it (9-11 ms), and an item not traced last frame is added only with ADD_SLACK to spare
    (set to 0.25 here, its value until 6 Dec 2026: with 0 the spare is none)."""
    monkeypatch.setattr(benefit_selection, "ADD_SLACK", 0.25)
    names, pixels, priors, cost = ["A"], [[0, 100, 0]], [[0, 0.1, 0]], [[0, 10, 0]]

    def measured_selector():
        selector = BenefitSelector()
        selector.estimates[("A", "reflections")] = 0.1  # measured before: no exploration bonus
        return selector
    added = choose(measured_selector(), names, pixels, priors, cost, 10.0 * (1 + benefit_selection.ADD_SLACK) - 0.1)
    assert not added.chosen.any()  # fits, but without room to spare
    selector = measured_selector()
    added = choose(selector, names, pixels, priors, cost, 10.0 * (1 + benefit_selection.ADD_SLACK) + 0.1)
    assert added.chosen[0, 1]
    selector.observe(names, added, np.asarray(priors, float))
    states = []
    for frame in range(20):
        choice = choose(selector, names, pixels, priors, cost, 9.0 if frame % 2 else 11.0)
        states.append(bool(choice.chosen[0, 1]))
        selector.observe(names, choice, np.asarray(priors, float))
    assert all(states), states
    # A real fall of the time left (below the held cost) drops it.
    choice = choose(selector, names, pixels, priors, cost, 10.0 * (1 - benefit_selection.HOLD) - 0.1)
    assert not choice.chosen.any()


def test_an_item_dropped_while_it_competed_rests_before_it_is_added_again():
    """The element stays traced (its cheap shadow): no flip of the element, only of its
    reflection, which waits REST frames (the element's flip guard does not apply)."""
    selector = BenefitSelector()
    names, pixels, priors = ["A"], [[100, 100, 0]], [[0.1, 0.1, 0]]
    cost = [[1, 10, 0]]
    selector.estimates[("A", "reflections")] = selector.estimates[("A", "shadows")] = 0.1
    choice = choose(selector, names, pixels, priors, cost, 20.0)
    assert choice.chosen[0, 1] and choice.chosen[0, 0]
    selector.observe(names, choice, np.asarray(priors, float))
    dropped = choose(selector, names, pixels, priors, cost, 5.0)  # the time left fell: dropped
    assert dropped.chosen.tolist() == [[True, False, False]]
    selector.observe(names, dropped, np.asarray(priors, float))
    back = []
    for _ in range(benefit_selection.REST + 1):
        choice = choose(selector, names, pixels, priors, cost, 20.0)
        back.append(bool(choice.chosen[0, 1]))
        selector.observe(names, choice, np.asarray(priors, float))
    # Dropped on one frame; back on the REST-th frame after it, not before.
    assert back == [False] * (benefit_selection.REST - 1) + [True, True], back


def test_an_item_that_left_the_view_does_not_rest_when_it_comes_back():
    selector = BenefitSelector()
    names, priors, cost = ["A"], [[0, 0.1, 0]], [[0, 10, 0]]
    selector.estimates[("A", "reflections")] = 0.1
    choice = choose(selector, names, [[0, 100, 0]], priors, cost, 20.0)
    selector.observe(names, choice, np.asarray(priors, float))
    gone = choose(selector, names, [[0, 0, 0]], priors, cost, 20.0)  # not visible: not eligible
    assert not gone.chosen.any()
    selector.observe(names, gone, np.asarray(priors, float))
    back = choose(selector, names, [[0, 100, 0]], priors, cost, 20.0)
    assert back.chosen[0, 1]


def test_an_item_is_added_for_the_time_left_recent_frames_could_count_on_not_for_one_peak():
    """Adds are sized for the STEADY_QUANTILE of the recent time left: one frame of uncommon room
    does not add an item that the ordinary frames around it could not pay (it would be dropped
    again on the next one); room that lasts does."""
    selector = BenefitSelector()
    names, pixels, priors, cost = ["A"], [[0, 100, 0]], [[0, 0.1, 0]], [[0, 10, 0]]
    selector.estimates[("A", "reflections")] = 0.1
    for _ in range(benefit_selection.STEADY_FRAMES):
        choice = choose(selector, names, pixels, priors, cost, 8.0)  # does not fit
        selector.observe(names, choice, np.asarray(priors, float))
    peak = choose(selector, names, pixels, priors, cost, 20.0)  # one frame with room
    assert not peak.chosen.any()
    selector.observe(names, peak, np.asarray(priors, float))
    states = []
    for _ in range(benefit_selection.STEADY_FRAMES):  # the room lasts: taken within the window
        choice = choose(selector, names, pixels, priors, cost, 20.0)
        states.append(bool(choice.chosen[0, 1]))
        selector.observe(names, choice, np.asarray(priors, float))
    assert any(states) and states[-1], states


def test_after_frames_with_no_time_left_nothing_is_added_and_no_nan_is_made():
    selector = BenefitSelector()
    names, pixels, priors = ["A", "Free"], [[0, 100, 0], [0, 100, 0]], [[0, 0.1, 0], [0, 0.1, 0]]
    selector.estimates[("A", "reflections")] = selector.estimates[("Free", "reflections")] = 0.1
    with np.errstate(invalid="raise", over="raise"):
        for _ in range(benefit_selection.STEADY_FRAMES):
            choice = choose(selector, names, pixels, priors, [[0, 10, 0], [0, 0, 0]], 0.0)
            selector.observe(names, choice, np.asarray(priors, float))
        choice = choose(selector, names, pixels, priors, [[0, 10, 0], [0, 0, 0]], 20.0)
    assert not choice.chosen[0].any()  # the recent frames could not count on any time
    assert np.all(np.isfinite(choice.cost_ms))


def test_an_element_dropped_whole_waits_the_flip_gap_whichever_of_its_effects_would_come_back():
    selector = BenefitSelector()
    names, priors = ["A"], [[0.1, 0.1, 0]]
    selector.estimates[("A", "shadows")] = selector.estimates[("A", "reflections")] = 0.1
    # Its reflection is traced; then the time left falls and the element is dropped.
    choice = choose(selector, names, [[10, 100, 0]], priors, [[1e3, 10, 0]], 20.0)
    assert choice.chosen.tolist() == [[False, True, False]]
    selector.observe(names, choice, np.asarray(priors, float))
    dropped = choose(selector, names, [[10, 100, 0]], priors, [[1e3, 10, 0]], 5.0)
    assert not dropped.chosen.any()
    selector.observe(names, dropped, np.asarray(priors, float))
    # Now its (never traced) shadow would fit: the element waits all the same, FLIP_GAP frames
    # after the drop (its flip), longer than the item's own REST.
    assert benefit_selection.FLIP_GAP > benefit_selection.REST
    states = []
    for _ in range(benefit_selection.FLIP_GAP):
        choice = choose(selector, names, [[10, 100, 0]], priors, [[2, 1e3, 0]], 20.0)
        states.append(bool(choice.chosen.any()))
        selector.observe(names, choice, np.asarray(priors, float))
    assert states == [False] * (benefit_selection.FLIP_GAP - 1) + [True], states


@pytest.mark.parametrize("tiers", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_no_element_flips_more_than_twice_in_10_frames_whatever_the_time_left_does(seed, tiers):
    """Three elements of one or two effects compete for a time left that jumps at random between
    none and all of them (the worst the raster half's noise can do) and leave the view now and
    then: each may be dropped on any frame the budget forces it, yet none flips
    more than twice within any 10 frames as the reports count flips
    (``runs.summary.max_flips_in_window``); and they are traced (the guard holds adds back, it
    does not shut tracing)."""
    rng = np.random.default_rng(seed)
    selector = BenefitSelector()
    names = ["A", "B", "C"]
    priors = np.asarray([[0.02, 0.1, 0], [0, 0.08, 0], [0.03, 0.05, 0]], float)
    for name, row in zip(names, priors):
        selector.estimates.update({(name, effect): float(value) for effect, value in
                                   zip(benefit_selection.EFFECTS, row) if value > 0})
    cost = np.asarray([[3, 6, 0], [0, 5, 0], [2, 4, 0]], float)
    states, rows = {name: [] for name in names}, []
    for frame in range(300):
        in_view = rng.random(3) > 0.1
        pixels = np.where(in_view[:, None] & (priors > 0), 100.0, 0.0)
        selector.observe_time(1.0, 1.0)
        choice = selector.choose(names, pixels > 0, pixels, priors, np.ones(3), cost,
                                 float(rng.choice([0.0, 5.0, 9.0, 16.0, 30.0])), 0.0, tiers=tiers)
        selector.observe(names, choice, priors)
        for i, name in enumerate(names):
            states[name].append(bool(choice.chosen[i].any()))
            rows.append({"frame": frame, "element": name, "selected": states[name][-1], "visible": bool(in_view[i])})
    assert run_summary.max_flips_in_window(rows, 10) <= 2
    assert all(sum(s) >= 15 for s in states.values()), {name: sum(s) for name, s in states.items()}


def test_the_flip_guard_counts_only_flips_in_view():
    """An element that leaves the view is not flipped (nobody sees it switch): when it comes back
    it is taken at once; an element dropped in view waits."""
    selector = BenefitSelector()
    names, priors, cost = ["A"], np.asarray([[0, 0.1, 0]], float), [[0, 10, 0]]
    selector.estimates[("A", "reflections")] = 0.1
    for pixels, time_left, expected in [([[0, 100, 0]], 20.0, True), ([[0, 0, 0]], 20.0, False),
                                        ([[0, 100, 0]], 20.0, True), ([[0, 100, 0]], 5.0, False),
                                        ([[0, 100, 0]], 20.0, False)]:
        choice = choose(selector, names, pixels, priors, cost, time_left)
        assert bool(choice.chosen.any()) == expected, (pixels, time_left)
        selector.observe(names, choice, priors)


def test_the_aim_keeps_the_share_of_frames_over_budget_at_its_target():
    """Frames of fixed planned work swing (lognormal, sigma 0.2: p95 about 1.39x the median): the
    aim settles where AIM_SHARE of the frames end over AIM_OVER x the budget, whether the plan
    started too greedy (every frame at the budget) or too timid (at 0.7 of it)."""
    budget = 50.0
    rng = np.random.default_rng(7)
    for planned_share in (1.0, 0.7):
        selector = BenefitSelector()
        over = []
        for frame in range(4000):
            # The frame's time: what it planned (aim x the planned share of the budget) times the noise.
            total = selector.aim * planned_share * budget * float(rng.lognormal(0.0, 0.2))
            selector.observe_frame(total, budget)
            over.append(total > benefit_selection.AIM_OVER * budget)
        share = float(np.mean(over[1000:]))
        assert abs(share - benefit_selection.AIM_SHARE) < 0.02, (planned_share, share)
        # The aim found the multiple of the budget whose 95th percentile is AIM_OVER x the budget.
        expected = benefit_selection.AIM_OVER / (planned_share * np.exp(0.2 * 1.645))
        expected = float(np.clip(expected, *benefit_selection.AIM_RANGE))
        assert selector.aim == pytest.approx(expected, rel=0.15)


def test_the_aim_moves_the_knapsacks_time_left_within_its_range_and_ignores_bad_numbers():
    selector = BenefitSelector()
    assert selector.aimed_time_left(20.0, 100.0) == pytest.approx(20.0)
    for _ in range(500):
        selector.observe_frame(200.0, 100.0)  # every frame twice over
    assert selector.aim == pytest.approx(benefit_selection.AIM_RANGE[0])
    assert selector.aimed_time_left(20.0, 100.0) == 0.0  # 20 - 50, never below 0
    for value in (np.nan, np.inf, -1.0):
        selector.observe_frame(value, 100.0)
        selector.observe_frame(50.0, value)
    assert selector.aim == pytest.approx(benefit_selection.AIM_RANGE[0])
    for _ in range(5000):
        selector.observe_frame(10.0, 100.0)  # every frame well within
    assert selector.aim == pytest.approx(benefit_selection.AIM_RANGE[1])
    assert selector.aimed_time_left(20.0, 100.0) == pytest.approx(45.0)
    assert np.isfinite(selector.aimed_time_left(20.0, np.nan))


def test_a_frame_over_budget_that_traced_nothing_does_not_lower_the_aim():
    selector = BenefitSelector()
    for _ in range(100):
        selector.observe_frame(200.0, 100.0, traced=False)  # the raster half alone overran
    assert selector.aim == pytest.approx(1.0)
    selector.observe_frame(200.0, 100.0, traced=True)
    assert selector.aim < 1.0
    before = selector.aim
    selector.observe_frame(50.0, 100.0, traced=False)  # room left, nothing bought: the aim may rise
    assert selector.aim > before


def test_the_short_percentile_is_numpys():
    from phrt.phrt_addon.select import frame_time
    rng = np.random.default_rng(3)
    for size in (1, 2, 3, 8, 20):
        values = rng.normal(0.0, 10.0, size)
        for q in (0, 25, 50, 80, 100):
            assert frame_time.percentile(values, q) == pytest.approx(float(np.percentile(values, q)), abs=1e-12)
