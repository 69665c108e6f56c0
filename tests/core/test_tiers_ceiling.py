"""Issue 23's ceiling: the exact multiple-choice knapsack over (element, effect, rate) options against
brute force, its candidates held to their measured time like the oracle's, and the oracle's forced
per-element rates."""
from itertools import product

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from phrt.phrt_addon.report import oracle_fit
from phrt.phrt_addon.report.tiers_ceiling import TierCandidates, exact_choices, exact_size
from phrt.phrt_addon.select import knapsack
from phrt.phrt_addon.trace.rates import forced_rates


def brute_force(values, costs, capacity):
    best, best_cost = 0.0, 0.0
    for picks in product(range(-1, values.shape[1]), repeat=len(values)):
        cost = sum(costs[i, o] for i, o in enumerate(picks) if o >= 0)
        value = sum(values[i, o] for i, o in enumerate(picks) if o >= 0)
        if cost <= capacity * (1 + 1e-12) and (value > best + 1e-12 or (abs(value - best) <= 1e-12 and cost < best_cost)):
            best, best_cost = value, cost
    return best, best_cost


def choice_instances(max_items, value, cost, capacity):
    """(values (n, 3), costs (n, 3), capacity) of up to ``max_items`` items of 3 options."""
    def rows(n, number):
        return st.lists(st.lists(number, min_size=3, max_size=3), min_size=n, max_size=n)
    return st.integers(0, max_items).flatmap(lambda n: st.tuples(rows(n, value), rows(n, cost), capacity))


instances = choice_instances(6, st.floats(0.0, 10.0), st.one_of(st.floats(0.0, 20.0), st.just(float("inf"))),
                             st.floats(0.0, 60.0))


@settings(max_examples=300, deadline=None)
@given(instances)
def test_exact_against_brute_force(instance):
    values = np.array(instance[0], np.float64).reshape(-1, 3)
    costs = np.array(instance[1], np.float64).reshape(-1, 3)
    capacity = instance[2]
    picked = exact_choices(values, costs, capacity)
    chosen = [(i, o) for i, o in enumerate(picked.tolist()) if o >= 0]
    cost = sum(costs[i, o] for i, o in chosen)
    value = sum(values[i, o] for i, o in chosen)
    best, best_cost = brute_force(values, costs, capacity)
    assert cost <= capacity * (1 + 1e-12)
    assert value == pytest.approx(best, abs=1e-9)


whole = choice_instances(5, st.integers(0, 6), st.integers(0, 9), st.integers(0, 30))


@settings(max_examples=200, deadline=None)
@given(whole)
def test_among_equal_values_the_cheaper_combination(instance):
    values = np.array(instance[0], np.float64).reshape(-1, 3)
    costs = np.array(instance[1], np.float64).reshape(-1, 3)
    picked = exact_choices(values, costs, float(instance[2]))
    chosen = [(i, o) for i, o in enumerate(picked.tolist()) if o >= 0]
    best, best_cost = brute_force(values, costs, instance[2])
    assert sum(values[i, o] for i, o in chosen) == best
    assert sum(costs[i, o] for i, o in chosen) == best_cost


def test_a_mirror_too_dear_at_full_rate_is_bought_at_quarter_rate():
    # One item: quarter 4 ms removes 0.6 of what full (14 ms) removes; 10 ms of room.
    picked = exact_choices(np.array([[0.6, 0.8, 1.0]]), np.array([[4.0, 7.0, 14.0]]), 10.0)
    assert picked.tolist() == [1]  # half rate: the most that fits
    picked = exact_choices(np.array([[0.6, 0.8, 1.0], [0.5, 0.7, 0.9]]), np.array([[4.0, 7.0, 14.0]] * 2), 10.0)
    assert sorted(picked.tolist()) == [0, 0]  # two quarters (1.1) beat one half and nothing (0.8)


def test_bad_numbers_and_no_time():
    values = np.array([[np.nan, 1.0, np.inf], [1.0, 1.0, 1.0]])
    costs = np.array([[1.0, np.nan, 1.0], [-2.0, 5.0, 5.0]])
    assert exact_choices(values, costs, -1.0).tolist() == [-1, -1]
    assert exact_choices(values, costs, float("nan")).tolist() == [-1, -1]
    picked = exact_choices(values, costs, 0.0)  # a negative cost counts as free
    assert picked.tolist() == [-1, 0]


def test_twenty_items_of_three_rates_are_exact_and_more_within_the_programmes_bound():
    """20 items of 3 rates (4^10 combinations a half) are solved exactly: nothing the binned
    programme finds is better, and moving any item to another option never gains within the time.
    Beyond that size, the programme: never over the time, at least half the best single option."""
    rng = np.random.default_rng(3)
    values, costs = rng.uniform(0, 1, (20, 3)), rng.uniform(1, 10, (20, 3))
    assert exact_size(costs) and not exact_size(rng.uniform(1, 10, (24, 3)))
    picked = exact_choices(values, costs, 30.0)
    chosen = [(i, o) for i, o in enumerate(picked.tolist()) if o >= 0]
    spent, got = sum(costs[i, o] for i, o in chosen), sum(values[i, o] for i, o in chosen)
    assert spent <= 30.0 * (1 + 1e-12)
    binned = knapsack.solve_choices(values, costs, 30.0)
    assert got >= sum(values[i, o] for i, o in enumerate(binned.tolist()) if o >= 0) - 1e-12
    for i in range(20):  # no single change of one item's option does better within the time
        for o in range(-1, 3):
            moved = picked.copy()
            moved[i] = o
            pairs = [(j, p) for j, p in enumerate(moved.tolist()) if p >= 0]
            if sum(costs[j, p] for j, p in pairs) <= 30.0:
                assert sum(values[j, p] for j, p in pairs) <= got + 1e-12
    values, costs = rng.uniform(0, 1, (30, 3)), rng.uniform(1, 10, (30, 3))
    picked = exact_choices(values, costs, 30.0)
    assert sum(costs[i, o] for i, o in enumerate(picked.tolist()) if o >= 0) <= 30.0 + 1e-9
    assert sum(values[i, o] for i, o in enumerate(picked.tolist()) if o >= 0) >= values[costs <= 30.0].max() / 2


def candidates():
    return TierCandidates(frame=4, items=[("Mirror", "reflections"), ("Oak", "shadows")], rates=(0.25, 0.5, 1.0),
                          cost_ms=np.array([[3.0, 5.0, 9.0], [4.0, 6.0, 8.0]]),
                          benefit=np.array([[0.004, 0.006, 0.007], [0.001, 0.002, 0.003]]),
                          flip_raster=0.02, overhead_ms=2.0)


def test_candidates_pay_the_fixed_part_once_and_name_their_rates():
    found = candidates()
    assert found.choose(1.9) == frozenset()
    chosen = found.choose(13.0)  # 11 ms of items: half mirror (5) + half oak (6)
    assert chosen == {("Mirror", "reflections", 0.5), ("Oak", "shadows", 0.5)}
    assert found.totals(chosen) == pytest.approx((13.0, 0.008))
    assert found.totals(frozenset()) == (0.0, 0.0)
    found.allowed = np.array([[True] * 3, [False, False, True]])  # shadows at full rate only
    assert found.choose(13.0) == {("Mirror", "reflections", 1.0)}


def test_a_combination_over_its_time_is_chosen_again():
    found = candidates()
    measured = {}

    def measure(subset):  # the pair costs 6 ms more together than its parts
        cost, _ = found.totals(subset)
        return cost + (6.0 if len(subset) > 1 else 0.0), 0.01

    chosen, refits = oracle_fit.feasible_choice(found, 13.0, 20.0, measure, measured)
    assert refits == 1 and len(chosen) == 1
    assert measured[chosen][0] <= 13.0 + oracle_fit.OVER_ALLOWANCE * 20.0


def test_forced_rates_per_element_or_for_all():
    names = ["Mirror", "Oak", "Glass"]
    assert forced_rates(None, names) is None
    arrays = forced_rates({"reflections": 0.5, "shadows": {"Oak": 0.25}}, names)
    assert arrays["reflections"].tolist() == [0.5, 0.5, 0.5]
    assert arrays["shadows"].tolist() == [1.0, 0.25, 1.0]
    with pytest.raises(ValueError):
        forced_rates({"shadows": {"Oak": 0.3}}, names)
    with pytest.raises(ValueError, match="Oka"):
        forced_rates({"shadows": {"Oka": 0.5}}, names)


def test_the_tool_says_when_the_ceiling_rules_the_target_out(monkeypatch, tmp_path, capsys):
    """``tools/tiers_ceiling.py``: the table's verdict follows the ratio's interval (above 0.8: no
    choice of rates reaches issue 23's target), and a folder with no evaluation is a one-line error."""
    from pathlib import Path
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[2] / "tools"))
    import tiers_ceiling as tool
    rng = np.random.default_rng(1)
    rows = []
    for frame in range(40):
        benefit = 0.02 + 0.002 * rng.random()
        rows.append({"path": "far", "budget_at": 0.1, "frame": frame, "raster_flip": 0.021, "benefit_flip": benefit,
                     "ceiling_flip": 0.97 * benefit})
        rows.append({"path": "near", "budget_at": 0.5, "frame": frame, "raster_flip": 0.021, "benefit_flip": benefit,
                     "ceiling_flip": 0.5 * benefit})
    ratio, low, high = tool.ratio_interval([row["ceiling_flip"] for row in rows[::2]],
                                           [row["benefit_flip"] for row in rows[::2]])
    assert ratio == pytest.approx(0.97) and low <= ratio <= high
    table = tool.markdown(rows).splitlines()
    assert table[2].startswith("| far | 0.1 | 40 |") and table[2].endswith("| no |")
    assert table[3].startswith("| near | 0.5 |") and table[3].endswith("| yes |")
    assert tool.main(["--eval", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
