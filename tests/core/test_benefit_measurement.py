"""When a BENEFIT frame measures what its traced items changed
(``BenefitSelector.wants_measurement``, ``frame_time.MeasureCost``): the measurement costs ms the
knapsack does not plan, so it is taken from the time the chosen items leave; an item never
measured is measured at once; nothing goes unmeasured for more than MEASURE_STALE frames."""
import numpy as np
import pytest

from phrt.phrt_addon.select import benefit_selection
from phrt.phrt_addon.select.benefit_selection import MEASURE_EVERY, MEASURE_STALE, BenefitSelector
from phrt.phrt_addon.select.frame_time import MeasureCost
from phrt.phrt_addon.select.item_choice import ItemChoice

NAMES = ["Mirror", "Statue"]


def choice(capacity_ms, chosen_cost_ms):
    """A frame that traces the mirror's reflection at ``chosen_cost_ms`` in ``capacity_ms``."""
    chosen = np.zeros((2, 3), bool)
    chosen[0, 1] = True
    cost = np.where(chosen, chosen_cost_ms, 0.0)
    return ItemChoice(chosen=chosen, eligible=chosen.copy(), value=cost, cost_ms=cost, per_pixel=cost,
                      capacity_ms=capacity_ms, margin_ms=0.0, rate=chosen.astype(float), chosen_cost_ms=cost,
                      fixed_ms=1.0)


def measured_selector(measure_ms):
    """A selector whose mirror was measured once and whose measurements cost ``measure_ms``."""
    selector = BenefitSelector()
    selector.estimates[("Mirror", "reflections")] = 0.2
    selector.measured_at[("Mirror", "reflections")] = 1.0  # measured at full rate
    for _ in range(4):
        selector.observe_measure_cost(True, 10.0 + measure_ms)
        selector.observe_measure_cost(False, 10.0)
    return selector


def test_the_measurement_cost_is_the_median_difference_and_unknown_before_two_of_each():
    cost = MeasureCost()
    assert cost.cost_ms() is None
    for ms in (12.0, 13.0, 40.0):  # one outlier
        cost.observe(True, ms)
    cost.observe(False, 10.0)
    assert cost.cost_ms() is None  # one plain frame: not yet
    cost.observe(False, 11.0)
    assert cost.cost_ms() == 13.0 - 10.5
    cost.observe(True, float("nan"))  # ignored
    assert cost.cost_ms() == 13.0 - 10.5
    for _ in range(8):
        cost.observe(True, 9.0)  # measuring cheaper than not (noise): costs nothing, never negative
    assert cost.cost_ms() == 0.0


def test_a_frame_measures_when_the_time_its_items_leave_pays_for_it():
    selector = measured_selector(3.0)
    # 10 ms of capacity, 8 ms of items and 1 ms of fixed part: 1 ms spare, the measurement costs 3.
    tight = [selector.wants_measurement(NAMES, choice(10.0, 8.0), frame) for frame in range(20, 21 + MEASURE_STALE)]
    # Never measured in this replay: measured at once; then only when MEASURE_STALE frames went by.
    assert tight == [True] + [False] * (MEASURE_STALE - 1) + [True]
    roomy = [selector.wants_measurement(NAMES, choice(20.0, 8.0), frame) for frame in range(40, 48)]
    assert roomy == [True, False] * 4  # every MEASURE_EVERY-th frame, as before
    assert MEASURE_EVERY == 2


def test_before_its_cost_is_known_a_frame_measures_every_other_frame():
    selector = BenefitSelector()
    selector.estimates[("Mirror", "reflections")] = 0.2
    selector.measured_at[("Mirror", "reflections")] = 1.0
    wanted = [selector.wants_measurement(NAMES, choice(10.0, 9.5), frame) for frame in range(1, 9)]
    assert wanted == [True, False] * 4


def test_an_item_never_measured_is_measured_on_its_first_traced_frame_whatever_the_time():
    selector = measured_selector(5.0)
    assert selector.wants_measurement(NAMES, choice(10.0, 8.0), 30)  # stale: first of all
    assert not selector.wants_measurement(NAMES, choice(10.0, 8.0), 31)
    del selector.estimates[("Mirror", "reflections")]  # as if the mirror had never been measured
    del selector.measured_at[("Mirror", "reflections")]
    assert selector.wants_measurement(NAMES, choice(10.0, 8.0), 32)


def test_no_measurement_rule_reads_milliseconds_of_this_machine():
    """The rule compares ms with ms measured in the same replay: on a machine twice as fast (every
    time halved) the same decisions."""
    slow, fast = measured_selector(4.0), measured_selector(4.0)
    for samples in (fast.measure_cost.plain, fast.measure_cost.measured):
        halved = [value / 2.0 for value in samples]
        samples.clear()
        samples.extend(halved)
    assert fast.measure_cost.cost_ms() == slow.measure_cost.cost_ms() / 2.0
    spares = [(12.0, 8.0), (14.0, 8.0), (10.0, 9.5), (30.0, 2.0)] * 4

    def decide(selector, scale):
        return [selector.wants_measurement(NAMES, choice(capacity * scale, cost * scale), frame)
                for frame, (capacity, cost) in enumerate(spares, 50)]
    assert decide(slow, 1.0) == decide(fast, 0.5)


def test_a_traced_item_keeps_its_estimate_between_measurements_and_an_untraced_one_decays():
    """Only an item not traced is pulled towards its prior (DECAY a frame): a traced item whose
    frame did not measure keeps what it was measured at (measured every 8th frame at most, it
    drifted 30-40% of the way to its prior between measurements)."""
    selector = BenefitSelector()
    selector.estimates[("Mirror", "reflections")] = 0.1
    selector.estimates[("Statue", "reflections")] = 0.1
    traced = choice(20.0, 8.0)  # the mirror's reflection traced, the statue's visible and not
    traced.eligible[1, 1] = True
    priors = np.full((2, 3), 0.5)
    for _ in range(7):
        selector.observe(NAMES, traced, priors, measured=None, pixels=np.full((2, 3), 100.0))
    assert selector.estimates[("Mirror", "reflections")] == 0.1
    decayed = 0.5 - 0.4 * (1.0 - benefit_selection.DECAY) ** 7
    assert selector.estimates[("Statue", "reflections")] == pytest.approx(decayed)


def test_a_rate_other_than_at_the_last_measurement_is_measured_at_once():
    """Quality tiers learn the share a rate keeps from a measurement at that rate after one at full
    rate: a change of rate is measured on its first frame, whatever the time left."""
    selector = measured_selector(5.0)
    assert selector.wants_measurement(NAMES, choice(10.0, 8.0), 30)  # stale: measured
    assert not selector.wants_measurement(NAMES, choice(10.0, 8.0), 31)
    quarter = choice(10.0, 8.0)
    quarter.rate = np.where(quarter.chosen, 0.25, 0.0)
    assert selector.wants_measurement(NAMES, quarter, 32)
