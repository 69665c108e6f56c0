"""The oracle's subset held to its time (phrt_addon/report/oracle_fit.py): a subset whose measured
trace is over the budget's time for tracing (plus the p95 allowance) is chosen again with what it
took beyond its parts charged; the best measured subset within time when no choice fits.  Plain
numpy: the renders are a table of measured times."""
import numpy as np
import pytest

from phrt.phrt_addon.report import oracle, oracle_fit


def frame_candidates():
    # Alone: mirror 10 ms, glass 6, fence 2 (beyond the 1 ms paid once a frame).
    return oracle.FrameCandidates(frame=4, names=["mirror", "glass", "fence"], cost_ms=np.array([10.0, 6.0, 2.0]),
                                  benefit=np.array([0.03, 0.02, 0.005]), flip_raster=0.10, overhead_ms=1.0)


def measured_table(times, flips):
    calls = []

    def measure(subset):
        calls.append(subset)
        return times[subset], flips[subset]
    return measure, calls


def test_a_subset_that_fits_as_predicted_is_the_oracle_and_measured_once():
    frame = frame_candidates()
    both = frozenset({"mirror", "glass"})
    measure, calls = measured_table({both: 17.5}, {both: 0.05})
    assert oracle_fit.feasible_choice(frame, 17.0, 60.0, measure) == (both, 0)  # 17.5 <= 17 + 6
    assert calls == [both]


def test_a_subset_over_its_time_together_is_chosen_again_with_its_excess_charged():
    """The mirror and the glass are predicted 17 ms and take 30 together (13 more than their parts):
    the next choice gets 17 - 13 = 4 ms: the fence (3 ms with the fixed part), which fits."""
    frame = frame_candidates()
    both, fence = frozenset({"mirror", "glass"}), frozenset({"fence"})
    measure, calls = measured_table({both: 30.0, fence: 3.2}, {both: 0.05, fence: 0.095})
    chosen, refits = oracle_fit.feasible_choice(frame, 17.0, 60.0, measure)
    assert (chosen, refits) == (fence, 1) and calls == [both, fence]
    # Within the allowance (a tenth of the budget) the first choice stands.
    measure, _ = measured_table({both: 22.9}, {both: 0.05})
    assert oracle_fit.feasible_choice(frame, 17.0, 60.0, measure) == (both, 0)


def test_when_no_choice_fits_the_best_measured_subset_within_time_is_the_oracle():
    frame = frame_candidates()
    alone = {frozenset({name}): (ms + 1.0, flip) for name, ms, flip in
             [("mirror", 10.0, 0.07), ("glass", 6.0, 0.08), ("fence", 2.0, 0.095)]}
    known = dict(alone)
    known[frozenset()] = (0.0, 0.10)
    # Every choice takes 40 ms more than predicted: none fits, whatever is charged.
    measure, calls = measured_table({s: frame.totals(s)[0] + 40.0 for s in
                                     [frozenset(c) for c in ({"mirror", "glass"}, {"mirror"}, {"glass"}, {"fence"},
                                                             {"glass", "fence"}, {"mirror", "fence"})]},
                                    {s: 0.01 for s in [frozenset({"mirror", "glass"})]})
    chosen, refits = oracle_fit.feasible_choice(frame, 17.0, 60.0, measure, known)
    assert refits >= 1 and len(calls) <= oracle_fit.REFITS + 1
    # Of the subsets measured within the 17 ms themselves, the lowest LDR-FLIP: the mirror alone (11 ms, 0.07).
    assert chosen == frozenset({"mirror"})
    # Nothing measured within time: the raster frame.
    assert oracle_fit.feasible_choice(frame, 17.0, 60.0, measure, {})[0] == frozenset()
    # Nothing fits the capacity in the first place: the raster frame, nothing rendered.
    measure, calls = measured_table({}, {})
    assert oracle_fit.feasible_choice(frame, 2.0, 60.0, measure, dict(known)) == (frozenset(), 0) and calls == []


def test_the_allowance_is_the_runs_p95_allowance_of_the_budget():
    assert oracle_fit.within_time(23.0, 17.0, 60.0) and not oracle_fit.within_time(23.1, 17.0, 60.0)
    assert oracle_fit.within_time(0.0, 0.0, 0.0) and not oracle_fit.within_time(0.1, 0.0, -5.0)
    assert oracle_fit.OVER_ALLOWANCE == pytest.approx(0.10)


def test_the_oracles_clock_follows_the_machine_against_the_runs_g_buffer_pass():
    """Per sampled frame the median of the oracle's G-buffer timings over the runs' raster run's on
    it; the ratio used is the median of the last CLOCK_WINDOW frames' (it follows a drift), clamped;
    frames without both numbers do not count; 1 before any has them."""
    clock = oracle_fit.Clock()
    assert clock.observe([None, float("nan")], 40.0) == 1.0  # nothing measured yet
    assert clock.observe([60.0, 66.0, 54.0], 50.0) == pytest.approx(1.2)
    assert clock.observe([48.0, 48.0, 47.0], None) == pytest.approx(1.2)  # no run timing: not counted
    for _ in range(oracle_fit.CLOCK_WINDOW):  # the machine slows down to 1.5x: the window follows
        ratio = clock.observe([75.0, 75.0, 75.0], 50.0)
    assert ratio == pytest.approx(1.5)
    assert oracle_fit.Clock().observe([500.0], 50.0) == oracle_fit.CLOCK_RANGE[1]
    summary = clock.summary()
    assert summary["clock_frames"] == 1 + oracle_fit.CLOCK_WINDOW
    assert summary["clock_ratio_min"] == 1.0 and summary["clock_ratio_max"] == pytest.approx(1.5)


def test_choices_that_keep_overrunning_stop_after_refits():
    """Every subset traced takes 47 ms, over the 40 ms capacity and its allowance (6): re-chosen
    REFITS times (each time the room shrinks by what the last took beyond its parts), no more, then
    the raster frame (nothing measured fits the 40 ms)."""
    frame = oracle.FrameCandidates(frame=4, names=[f"e{i}" for i in range(8)], cost_ms=np.full(8, 6.0),
                                   benefit=np.linspace(0.02, 0.01, 8), flip_raster=0.10, overhead_ms=0.0)
    calls = []

    def measure(subset):
        calls.append(subset)
        return 47.0, 0.05

    chosen, refits = oracle_fit.feasible_choice(frame, 40.0, 60.0, measure, {frozenset(): (0.0, 0.10)})
    assert refits == oracle_fit.REFITS and [len(subset) for subset in calls] == [6, 4, 1]
    assert chosen == frozenset()
