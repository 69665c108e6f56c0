"""The BENEFIT selection's knapsack against brute force: never over T, optimal within the bins."""
from itertools import product

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from phrt_addon.select import knapsack


def brute_force(values, costs, capacity):
    best, best_mask = 0.0, np.zeros(len(values), bool)
    for bits in product((False, True), repeat=len(values)):
        mask = np.array(bits, bool)
        if costs[mask].sum() <= capacity and values[mask].sum() > best:
            best, best_mask = values[mask].sum(), mask
    return best, best_mask


instances = st.integers(1, 10).flatmap(lambda n: st.tuples(
    st.lists(st.floats(0.0, 10.0), min_size=n, max_size=n),
    st.lists(st.floats(0.0, 20.0), min_size=n, max_size=n),
    st.floats(0.0, 60.0)))


@settings(max_examples=300, deadline=None)
@given(instances)
def test_never_over_capacity_and_optimal_within_the_rounding(instance):
    values, costs, capacity = np.array(instance[0]), np.array(instance[1]), instance[2]
    chosen = knapsack.solve(values, costs, capacity)
    assert costs[chosen].sum() <= capacity * (1 + 1e-8)
    optimum, _ = brute_force(values, costs, capacity)
    # Each chosen item loses at most one bin of T to the rounding: the optimum of a capacity
    # smaller by n bins is reached.
    shrunk, _ = brute_force(values, costs, capacity * (1.0 - len(values) / knapsack.bins_for(len(values))))
    assert values[chosen].sum() >= shrunk - 1e-9
    assert values[chosen].sum() <= optimum + 1e-9
    assert values[chosen].sum() >= optimum / 2 - 1e-9  # the best-single-item guard


def test_exact_when_costs_are_whole_bins():
    values = np.array([6.0, 10.0, 12.0])
    costs = np.array([0.64, 1.0, 1.56])  # 64, 100 and 156 of the 256 bins of T = 2.56
    chosen = knapsack.solve(values, costs, 2.56)
    assert chosen.tolist() == [False, True, True]


def test_free_items_are_taken_and_worthless_ones_never():
    chosen = knapsack.solve([1.0, 0.0, 5.0, -1.0], [0.0, 0.0, 100.0, 1.0], 10.0)
    assert chosen.tolist() == [True, False, False, False]


def test_bad_numbers_and_no_time():
    assert not knapsack.solve([np.nan, np.inf], [1.0, np.nan], 0.0).any()
    chosen = knapsack.solve([np.nan, 2.0], [1.0, 1.0], np.inf)
    assert chosen.tolist() == [False, True]
    assert knapsack.solve([], [], 5.0).shape == (0,)


def test_the_core_of_a_large_instance_is_close_to_the_exact_programme():
    rng = np.random.default_rng(7)
    values, costs = rng.random(3000), rng.random(3000) * 5
    capacity = costs.sum() * 0.2
    large = knapsack.solve(values, costs, capacity)
    assert costs[large].sum() <= capacity
    greedy_order = np.argsort(-values / costs)
    greedy = greedy_order[np.cumsum(costs[greedy_order]) <= capacity]
    # The core solution is within 0.5% of the ratio greedy's value (measured 0.998 on this
    # instance: the core's costs are rounded to bins, the greedy's prefix is not).
    assert values[large].sum() >= values[greedy].sum() * 0.995


choice_instances = st.integers(1, 6).flatmap(lambda n: st.tuples(
    st.lists(st.lists(st.floats(0.0, 10.0), min_size=3, max_size=3), min_size=n, max_size=n),
    st.lists(st.lists(st.floats(0.0, 20.0), min_size=3, max_size=3), min_size=n, max_size=n),
    st.floats(0.0, 60.0)))


def brute_force_choices(values, costs, capacity):
    best = 0.0
    for picks in product(range(-1, values.shape[1]), repeat=len(values)):
        cost = sum(costs[i, o] for i, o in enumerate(picks) if o >= 0)
        value = sum(values[i, o] for i, o in enumerate(picks) if o >= 0)
        if cost <= capacity and value > best:
            best = value
    return best


@settings(max_examples=200, deadline=None)
@given(choice_instances)
def test_multiple_choice_never_over_capacity_and_optimal_within_the_rounding(instance):
    values, costs, capacity = np.array(instance[0]), np.array(instance[1]), instance[2]
    choice = knapsack.solve_choices(values, costs, capacity)
    picked = [(i, o) for i, o in enumerate(choice.tolist()) if o >= 0]
    assert sum(costs[i, o] for i, o in picked) <= capacity * (1 + 1e-8)
    got = sum(values[i, o] for i, o in picked)
    optimum = brute_force_choices(values, costs, capacity)
    shrunk = brute_force_choices(values, costs, capacity * (1.0 - len(values) / knapsack.bins_for(len(values))))
    assert shrunk - 1e-9 <= got <= optimum + 1e-9
    assert got >= optimum / 2 - 1e-9


def test_multiple_choice_takes_a_cheaper_rate_when_full_does_not_fit():
    # One item: full (value 10, cost 8), half (8.5, 4.4), quarter (6.5, 2.6); T = 5: half.
    choice = knapsack.solve_choices([[10.0, 8.5, 6.5]], [[8.0, 4.4, 2.6]], 5.0)
    assert choice.tolist() == [1]
    # Two such items in T = 8: both at quarter/half beat one at full.
    choice = knapsack.solve_choices([[10.0, 8.5, 6.5]] * 2, [[8.0, 4.4, 2.6]] * 2, 8.0)
    assert sorted(choice.tolist()) == [1, 2]


def grouped_brute_force(values, costs, groups, group_costs, capacity):
    """The 0/1 case: one option per item."""
    return grouped_choices_brute_force(values[:, None], costs[:, None], groups, group_costs, capacity)


grouped_instances = st.integers(1, 8).flatmap(lambda n: st.tuples(
    st.lists(st.floats(0.0, 10.0), min_size=n, max_size=n),
    st.lists(st.floats(0.0, 20.0), min_size=n, max_size=n),
    st.lists(st.integers(0, 2), min_size=n, max_size=n),
    st.lists(st.floats(0.0, 15.0), min_size=3, max_size=3),
    st.floats(0.0, 60.0)))


def programme_and_enumeration(solve) -> list:
    """``solve()``'s answers by the binned programme (ENUMERATE_LIMIT 0) and as it is (a few
    useful items: the enumeration), so both paths stay tested on small instances."""
    limit = knapsack.ENUMERATE_LIMIT
    try:
        knapsack.ENUMERATE_LIMIT = 0
        programme = solve()
    finally:
        knapsack.ENUMERATE_LIMIT = limit
    return [programme, solve()]


@settings(max_examples=300, deadline=None)
@given(grouped_instances)
def test_grouped_never_over_capacity_and_optimal_within_the_rounding(instance):
    """A group's cost (an effect's fixed work) is paid once when any of its items is chosen."""
    values, costs, groups, group_costs, capacity = (np.array(instance[0]), np.array(instance[1]),
                                                    np.array(instance[2]), np.array(instance[3]), instance[4])
    optimum = grouped_brute_force(values, costs, groups, group_costs, capacity)
    # Each chosen item and each opened group loses at most one bin to the rounding.
    n_bins = knapsack.bins_for(len(values) + len(group_costs))
    shrunk = grouped_brute_force(values, costs, groups, group_costs,
                                 capacity * (1.0 - (len(values) + len(group_costs)) / n_bins))
    for chosen in programme_and_enumeration(lambda: knapsack.solve_grouped(values, costs, groups, group_costs,
                                                                           capacity)):
        spent = costs[chosen].sum() + group_costs[np.unique(groups[chosen])].sum()
        assert spent <= capacity * (1 + 1e-8)
        assert optimum + 1e-9 >= values[chosen].sum() >= shrunk - 1e-9


def test_grouped_leaves_a_group_whose_fixed_cost_buys_less_than_another():
    """Two cheap shadow items behind a 4 ms fixed part against one reflection item with none:
    5 ms of time buys the reflection (4 + 2 x 0.6 > 5 leaves the shadows out)."""
    values, costs, groups = np.array([3.0, 3.0, 4.0]), np.array([0.6, 0.6, 4.5]), np.array([0, 0, 1])
    for chosen in programme_and_enumeration(
            lambda: knapsack.solve_grouped(values, costs, groups, np.array([4.0, 0.0, 0.0]), 5.0)):
        assert chosen.tolist() == [False, False, True]
    # With 6 ms both shadow items fit behind their fixed part (6 > 4 + 1.2) and are worth more.
    for chosen in programme_and_enumeration(
            lambda: knapsack.solve_grouped(values, costs, groups, np.array([4.0, 0.0, 0.0]), 6.0)):
        assert chosen.tolist() == [True, True, False]


def grouped_choices_brute_force(values, costs, groups, group_costs, capacity):
    best = 0.0
    n, k = values.shape
    for options in product(range(-1, k), repeat=n):
        picked = [(i, o) for i, o in enumerate(options) if o >= 0]
        used = {groups[i] for i, _ in picked}
        spent = sum(costs[i, o] for i, o in picked) + sum(group_costs[g] for g in used)
        if spent <= capacity:
            best = max(best, sum(values[i, o] for i, o in picked))
    return best


grouped_choice_instances = st.integers(1, 5).flatmap(lambda n: st.tuples(
    st.lists(st.lists(st.floats(0.0, 10.0), min_size=3, max_size=3), min_size=n, max_size=n),
    st.lists(st.lists(st.floats(0.0, 20.0), min_size=3, max_size=3), min_size=n, max_size=n),
    st.lists(st.integers(0, 2), min_size=n, max_size=n),
    st.lists(st.floats(0.0, 15.0), min_size=3, max_size=3),
    st.floats(0.0, 60.0)))


@settings(max_examples=200, deadline=None)
@given(grouped_choice_instances)
def test_grouped_multiple_choice_never_over_capacity_and_optimal_within_the_rounding(instance):
    values, costs, groups, group_costs, capacity = (np.array(instance[0]), np.array(instance[1]),
                                                    np.array(instance[2]), np.array(instance[3]), instance[4])
    choice = knapsack.solve_choices(values, costs, capacity, groups=groups, group_costs=group_costs)
    picked = [(i, o) for i, o in enumerate(choice.tolist()) if o >= 0]
    spent = sum(costs[i, o] for i, o in picked) + sum(group_costs[g] for g in {groups[i] for i, _ in picked})
    assert spent <= capacity * (1 + 1e-8)
    got = sum(values[i, o] for i, o in picked)
    n_bins = knapsack.bins_for(len(values) + len(group_costs))
    shrunk = grouped_choices_brute_force(values, costs, groups, group_costs,
                                         capacity * (1.0 - (len(values) + len(group_costs)) / n_bins))
    assert grouped_choices_brute_force(values, costs, groups, group_costs, capacity) + 1e-9 >= got >= shrunk - 1e-9


def test_one_effects_fixed_part_does_not_block_the_others():
    """A shadow group whose fixed part is the whole time left and a reflection at quarter rate
    that fits: the reflection is bought (paying every effect's fixed part up front bought nothing)."""
    values = np.array([[5.0, 0.0, 0.0], [4.0, 3.4, 2.6]])
    costs = np.array([[1.0, np.inf, np.inf], [8.0, 6.0, 3.0]])
    choice = knapsack.solve_choices(values, costs, 5.0, groups=[0, 1], group_costs=[5.0, 1.0])
    assert choice.tolist() == [-1, 2]


def test_beyond_the_exact_limit_groups_are_paid_only_when_they_buy_something():
    rng = np.random.default_rng(3)
    n = knapsack.EXACT_LIMIT + 200
    values, costs = rng.uniform(0.1, 1.0, n), rng.uniform(0.1, 1.0, n)
    groups = np.where(np.arange(n) < 10, 0, 1)  # group 0: ten items behind a fixed part of 80
    chosen = knapsack.solve_grouped(values, costs, groups, np.array([80.0, 1.0]), 50.0)
    assert chosen.any() and not chosen[:10].any()
    assert costs[chosen].sum() + 1.0 <= 50.0 + 1e-9


def test_grouped_takes_free_items_with_no_time_left_beyond_the_exact_limit():
    """T = 0: items of cost 0 in a group of cost 0 are free (hypothesis found the fallback missing them)."""
    for chosen in programme_and_enumeration(
            lambda: knapsack.solve_grouped([1.0, 1.0], [0.0, 0.0], [0, 0], [0.0, 0.0, 0.0], 0.0)):
        assert chosen.tolist() == [True, True]
    for chosen in programme_and_enumeration(
            lambda: knapsack.solve_grouped([1.0, 1.0], [0.0, 0.0], [0, 0], [1.0, 0.0, 0.0], 0.0)):
        assert chosen.tolist() == [False, False]
    # A free item whose value is lost in the sum beside a large one is taken all the same.
    assert knapsack.solve_grouped([1e-300, 1.0], [0.0, 0.0], [0, 0], [0.0], 0.0).tolist() == [True, True]


@settings(max_examples=300, deadline=None)
@given(grouped_instances)
def test_grouped_with_few_useful_items_is_the_exact_optimum(instance):
    """Up to ENUMERATE_LIMIT useful items every subset is tried on the costs as they are: the
    optimum itself, no bin lost to rounding, never over the time."""
    values, costs, groups, group_costs, capacity = (np.array(instance[0]), np.array(instance[1]),
                                                    np.array(instance[2]), np.array(instance[3]), instance[4])
    assert len(values) <= knapsack.ENUMERATE_LIMIT
    chosen = knapsack.solve_grouped(values, costs, groups, group_costs, capacity)
    assert costs[chosen].sum() + group_costs[np.unique(groups[chosen])].sum() <= capacity * (1 + 1e-12)
    assert values[chosen].sum() == pytest.approx(grouped_brute_force(values, costs, groups, group_costs, capacity),
                                                 abs=1e-9)


@settings(max_examples=200, deadline=None)
@given(grouped_choice_instances)
def test_multiple_choice_beyond_the_exact_limit_is_never_over_T_and_at_least_half_the_optimum(instance):
    """The increments' greedy (``knapsack_greedy``, what ``solve_choices`` runs beyond EXACT_LIMIT
    items), here on a few items so that brute force can judge it: never over T with the groups'
    costs; with the best single option beside it, at least half of the optimum (no groups)."""
    values, costs, groups, group_costs, capacity = (np.array(instance[0]), np.array(instance[1]),
                                                    np.array(instance[2]), np.array(instance[3]), instance[4])
    limit = knapsack.EXACT_LIMIT
    knapsack.EXACT_LIMIT = 0
    try:
        grouped = knapsack.solve_choices(values, costs, capacity, groups=groups, group_costs=group_costs)
        plain = knapsack.solve_choices(values, costs, capacity)
    finally:
        knapsack.EXACT_LIMIT = limit
    picked = [(i, o) for i, o in enumerate(grouped.tolist()) if o >= 0]
    spent = sum(costs[i, o] for i, o in picked) + sum(group_costs[g] for g in {groups[i] for i, _ in picked})
    assert spent <= capacity * (1 + 1e-12)
    picked = [(i, o) for i, o in enumerate(plain.tolist()) if o >= 0]
    assert sum(costs[i, o] for i, o in picked) <= capacity * (1 + 1e-12)
    optimum = grouped_choices_brute_force(values, costs, np.zeros(len(values), int), np.zeros(1), capacity)
    assert sum(values[i, o] for i, o in picked) >= 0.5 * optimum - 1e-9


def test_multiple_choice_beyond_the_exact_limit_fills_T_at_least_as_well_as_the_programme():
    """1,200 items of three rates (quality tiers on a large scene), an effect's fixed part per
    group: the greedy on true costs is never over T and worth at least the binned programme's
    choice on the same items (which loses up to a bin per chosen item to the rounding)."""
    rng = np.random.default_rng(5)
    n = knapsack.EXACT_LIMIT + 200
    full_value, full_cost = rng.uniform(0, 10, n), rng.uniform(0.5, 5, n)
    values = np.where(rng.random((n, 3)) < 0.9, np.outer(full_value, [1.0, 0.85, 0.65]), 0.0)
    costs = np.outer(full_cost, [1.0, 0.6, 0.35])
    groups, group_costs, capacity = rng.integers(0, 3, n), np.array([2.0, 1.0, 1.5]), float(full_cost.sum() / 3)

    def outcome(choice):
        picked = [(i, o) for i, o in enumerate(choice.tolist()) if o >= 0]
        spent = sum(costs[i, o] for i, o in picked) + sum(group_costs[g] for g in {groups[i] for i, _ in picked})
        return sum(values[i, o] for i, o in picked), spent

    greedy_value, greedy_spent = outcome(knapsack.solve_choices(values, costs, capacity, groups=groups,
                                                                 group_costs=group_costs))
    limit = knapsack.EXACT_LIMIT
    knapsack.EXACT_LIMIT = 10 * n
    try:
        exact_value, _ = outcome(knapsack.solve_choices(values, costs, capacity, groups=groups, group_costs=group_costs))
    finally:
        knapsack.EXACT_LIMIT = limit
    assert greedy_spent <= capacity
    assert greedy_value >= exact_value


def test_the_greedy_keeps_the_more_valuable_of_free_options():
    """Options of cost 0 all have an infinite value per ms: of two, the more valuable is the one taken
    (found in review: the first by column was taken, and the better one dropped)."""
    limit = knapsack.EXACT_LIMIT
    knapsack.EXACT_LIMIT = 0
    try:
        choice = knapsack.solve_choices([[1.0, 5.0]] * 3, [[0.0, 0.0]] * 3, 10.0)
    finally:
        knapsack.EXACT_LIMIT = limit
    assert choice.tolist() == [1, 1, 1]
