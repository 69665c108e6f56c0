"""The oracle's decisions and books (phrt_addon/report/oracle.py): exact knapsack, sampling, the
time the oracle may fill, and its folder read back.  No bpy (its renders are tested in
tests/integration/test_sweep.py)."""
import itertools
import json

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from phrt.phrt_addon.report import oracle


def brute_force(values, costs, capacity):
    best, best_cost = 0.0, 0.0
    for size in range(len(values) + 1):
        for subset in itertools.combinations(range(len(values)), size):
            cost = sum(costs[i] for i in subset)
            value = sum(values[i] for i in subset)
            if cost <= capacity and value > best + 1e-12:
                best, best_cost = value, cost
    return best


@settings(max_examples=150, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 10.0), st.floats(0.01, 10.0)), min_size=0, max_size=9),
       st.floats(0.0, 30.0))
def test_knapsack_is_exact_and_within_capacity(items, capacity):
    values = np.array([value for value, _ in items])
    costs = np.array([cost for _, cost in items])
    chosen = oracle.knapsack(values, costs, capacity)
    assert chosen.dtype == bool and chosen.shape == (len(items),)
    assert costs[chosen].sum() <= capacity + 1e-9
    assert values[chosen].sum() == pytest.approx(brute_force(values, costs, capacity), abs=1e-9)


def test_knapsack_prefers_value_over_relevance_order():
    # Greedy by value per cost takes the two small items (value 12); the optimum is the big one (15).
    values, costs = np.array([6.0, 6.0, 15.0]), np.array([4.0, 4.0, 10.0])
    assert oracle.knapsack(values, costs, 10.0).tolist() == [False, False, True]


def test_knapsack_takes_everything_when_it_fits_and_free_items_always():
    values, costs = np.array([1.0, 2.0, 3.0]), np.array([1.0, 1.0, 1.0])
    assert oracle.knapsack(values, costs, 3.0).all()
    assert oracle.knapsack(np.array([1.0, 5.0]), np.array([0.0, 9.0]), 1.0).tolist() == [True, False]
    assert not oracle.knapsack(values, costs, -1.0).any()
    assert oracle.knapsack(np.zeros(0), np.zeros(0), 5.0).shape == (0,)


def test_every_kth_frame_is_sampled_not_the_cold_first_one():
    assert oracle.sampled_frames(range(1, 25), 8) == [8, 16, 24]
    assert oracle.sampled_frames([5, 3, 4], 8) == [5]  # shorter than k: the last frame
    assert oracle.sampled_frames(range(1, 5), 1) == [1, 2, 3, 4]
    with pytest.raises(ValueError):
        oracle.sampled_frames([1, 2], 0)


def candidates(benefit, cost):
    names = [f"e{i}" for i in range(len(benefit))]
    return oracle.FrameCandidates(frame=8, names=names, cost_ms=np.array(cost, float), benefit=np.array(benefit, float),
                                  flip_raster=0.05)


def test_oracle_picks_the_larger_error_drop_when_only_one_fits():
    frame = candidates([0.02, 0.001], [10.0, 10.0])
    assert frame.choose(12.0) == {"e0"}
    assert frame.choose(20.0) == {"e0", "e1"}


def test_negative_measured_drops_count_as_noise_so_a_covering_budget_traces_all():
    frame = candidates([0.01, -0.0003, 0.0], [5.0, 5.0, 5.0])
    assert frame.choose(15.0) == {"e0", "e1", "e2"}


def test_results_round_trip_and_go_stale_when_a_run_is_redone(tmp_path):
    run = tmp_path / "run-a"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps({"frame_count": 8}))
    frame = candidates([0.02, 0.001], [10.0, 10.0])
    row = oracle.regret_row("run-a", 8, 60.0, 48.0, 9.0, {"e1"}, 0.04, frame.choose(12.0), 0.03, frame)
    assert row["regret"] == pytest.approx(0.01)
    assert row["oracle_only"] == "e0" and row["heuristic_only"] == "e1"
    info = oracle.write_results(tmp_path / "oracle", 8, [8], [frame], [row], {"run-a": run})
    assert info["runs"]["run-a"]["mean_regret"] == pytest.approx(0.01)
    results = oracle.read_results(tmp_path / "oracle")
    assert results.rows_of("run-a")[0]["oracle"] == ["e0"]
    assert results.rows_of("run-a")[0]["capacity_ms"] == pytest.approx(12.0)
    assert len(results.candidate_rows) == 2
    assert results.is_current_for("run-a", run)
    (run / "summary.json").write_text(json.dumps({"frame_count": 8, "redone": True}))
    assert not results.is_current_for("run-a", run)
    assert oracle.read_results(tmp_path / "missing") is None


def test_the_trace_stages_fixed_part_is_paid_once_per_frame():
    # Alone 12, 7 and 5 ms; together 18 ms: 6 ms of the 24 summed are the fixed part paid twice too often.
    assert oracle.trace_overhead_ms([12.0, 7.0, 5.0], 18.0) == pytest.approx(3.0)
    assert oracle.trace_overhead_ms([12.0, 7.0], 30.0) == 0.0  # never negative
    assert oracle.trace_overhead_ms([4.0, 9.0], 1.0) == 4.0  # at most the cheapest alone
    assert oracle.trace_overhead_ms([4.0], 4.0) == 0.0
    frame = oracle.FrameCandidates(frame=8, names=["a", "b"], cost_ms=np.array([9.0, 4.0]),
                                   benefit=np.array([0.02, 0.01]), flip_raster=0.05, overhead_ms=3.0)
    assert frame.totals({"a", "b"}) == (pytest.approx(16.0), pytest.approx(0.03))
    assert frame.totals(set()) == (0.0, 0.0)
    assert frame.choose(12.0) == {"a"} and frame.choose(16.0) == {"a", "b"} and frame.choose(2.0) == frozenset()
