"""The knapsacks' exact reduction (knapsack_bounds): the bound is an upper bound, fixing never
excludes every optimum, and the reduced programme returns what the whole programme returns."""
from itertools import product

import numpy as np
from hypothesis import given, settings, strategies as st

from phrt_addon.select import knapsack, knapsack_bounds


def optimum(values, weights, groups, group_weights, capacity, fixed=None):
    """Brute force over every choice (an option or -1 per item), whole-bin weights; ``fixed``: only
    the choices that agree with it where it is not FREE."""
    best = 0.0
    n, k = values.shape
    for options in product(range(-1, k), repeat=n):
        if fixed is not None and any(f != knapsack_bounds.FREE and f != o for f, o in zip(fixed, options)):
            continue
        picked = [(i, o) for i, o in enumerate(options) if o >= 0]
        if any(not np.isfinite(values[i, o]) for i, o in picked):
            continue
        used = {groups[i] for i, _ in picked}
        spent = sum(weights[i, o] for i, o in picked) + sum(group_weights[g] for g in used)
        if spent <= capacity:
            best = max(best, sum(values[i, o] for i, o in picked))
    return best


instances = st.tuples(st.integers(1, 6), st.integers(1, 3), st.integers(1, 3)).flatmap(
    lambda shape: st.tuples(
        st.lists(st.lists(st.one_of(st.floats(0.0, 50.0), st.just(-np.inf)), min_size=shape[1], max_size=shape[1]),
                 min_size=shape[0], max_size=shape[0]),
        st.lists(st.lists(st.integers(0, 12), min_size=shape[1], max_size=shape[1]),
                 min_size=shape[0], max_size=shape[0]),
        st.lists(st.integers(0, shape[2] - 1), min_size=shape[0], max_size=shape[0]),
        st.lists(st.integers(0, 6), min_size=shape[2], max_size=shape[2]),
        st.integers(0, 30), st.floats(0.0, 10.0)))


@settings(max_examples=300, deadline=None)
@given(instances)
def test_the_bound_holds_and_fixing_keeps_an_optimum(instance):
    values, weights, groups, group_weights, capacity, multiplier = (
        np.array(instance[0], float), np.array(instance[1], float), np.array(instance[2]),
        np.array(instance[3], float), instance[4], instance[5])
    best = optimum(values, weights, groups, group_weights, capacity)
    assert knapsack_bounds.bound(values, weights, groups, group_weights, capacity, [multiplier])[0] >= best - 1e-9
    lower, choice = knapsack_bounds.greedy(values, weights, groups, group_weights, capacity)
    picked = [(i, o) for i, o in enumerate(choice.tolist()) if o >= 0]
    spent = sum(weights[i, o] for i, o in picked) + sum(group_weights[g] for g in {groups[i] for i, _ in picked})
    assert spent <= capacity and abs(sum(values[i, o] for i, o in picked) - lower) < 1e-9 and lower <= best + 1e-9
    fixed = knapsack_bounds.reduce(values, weights, groups, group_weights, capacity)
    assert abs(optimum(values, weights, groups, group_weights, capacity, fixed) - best) < 1e-9
    # The break ratio the pre-test found, handed on to the reduction: still exact.
    ratio = knapsack_bounds.promising(values, weights, capacity, share=0.0)
    fixed = knapsack_bounds.reduce(values, weights, groups, group_weights, capacity, ratio)
    assert abs(optimum(values, weights, groups, group_weights, capacity, fixed) - best) < 1e-9


def frame_like(rng, n, options):
    """An instance like a frame's: values and costs spread, a third of the items fitting."""
    base = rng.integers(1, 5000, n) * rng.random(n) * 0.3
    values = base[:, None] * np.linspace(1.0, 0.4, options)[None, :]
    costs = rng.random(n)[:, None] * 5.0 * np.linspace(1.0, 0.3, options)[None, :] + 0.05
    groups = rng.integers(0, 3, n)
    return values, costs, groups, np.array([2.0, 1.0, 1.0]), float(costs[:, 0].sum() / 3)


def test_the_reduced_programme_returns_the_whole_programmes_choice(monkeypatch):
    """Above REDUCE_FROM items the reduction runs first; with it switched off the same choices."""
    rng = np.random.default_rng(7)
    instances = [frame_like(rng, int(rng.integers(knapsack.REDUCE_FROM, 300)), int(rng.integers(1, 4)))
                 for _ in range(40)]
    def solved(v, c, g, gc, cap):
        return (knapsack.solve_grouped(v[:, 0], c[:, 0], g, gc, cap), knapsack.solve(v[:, 0], c[:, 0], cap),
                knapsack.solve_choices(v, c, cap, groups=g, group_costs=gc))

    reduced = [solved(*instance) for instance in instances]
    monkeypatch.setattr(knapsack, "REDUCE_FROM", 10 ** 9)
    for instance, with_reduction in zip(instances, reduced):
        for whole, first_reduced in zip(solved(*instance), with_reduction):
            assert np.array_equal(whole, first_reduced)


def test_the_bound_fixes_most_items_of_a_frame_like_instance():
    """What makes the reduction worth its cost: on a frame-like instance of 150 items most are fixed."""
    rng = np.random.default_rng(11)
    values, costs, groups, group_costs, capacity = frame_like(rng, 150, 1)
    n_bins = knapsack.bins_for(150 + 3)
    weights = np.ceil(costs / capacity * n_bins)
    fixed = knapsack_bounds.reduce(values, weights, groups, np.ceil(group_costs / capacity * n_bins), n_bins)
    assert np.mean(fixed == knapsack_bounds.FREE) < 0.4


def exploring(rng, n):
    """An exploring frame's second knapsack: every item worth about the whole frame's value (the
    exploration's bonus) give or take a few percent, costs spread."""
    values = 15000.0 + rng.random(n) * 900.0
    costs = rng.random(n) * 5.0 + 0.05
    return values[:, None], costs[:, None], rng.integers(0, 3, n), np.array([0.0, 0.0, 0.0]), float(costs.sum() / 3)


def test_the_pre_test_skips_the_reduction_only_where_it_would_fix_little():
    """``promising``: yes on frame-like instances (the reduction fixes most of their items), no on
    an exploring frame's, where the bound's gap is one item wide and the reduction fixes none."""
    rng = np.random.default_rng(5)
    for options in (1, 2, 3):
        values, costs, groups, group_costs, capacity = frame_like(rng, 150, options)
        n_bins = knapsack.bins_for(150 + 3)
        assert knapsack_bounds.promising(values, np.ceil(costs / capacity * n_bins), n_bins) is not None
    values, costs, groups, group_costs, capacity = exploring(rng, 90)
    n_bins = knapsack.bins_for(90 + 3)
    weights = np.ceil(costs / capacity * n_bins)
    assert knapsack_bounds.promising(values, weights, n_bins) is None
    fixed = knapsack_bounds.reduce(values, weights, groups, group_costs, n_bins)
    assert np.mean(fixed == knapsack_bounds.FREE) > 0.75  # what the skip saves: a reduction that fixes little


def test_skipping_the_reduction_changes_no_choice(monkeypatch):
    """The pre-test only decides how the optimum is found: forced to run the reduction everywhere,
    or to skip it everywhere, the programme returns the same choices (exploring and frame-like)."""
    rng = np.random.default_rng(9)
    instances = [exploring(rng, int(rng.integers(knapsack.REDUCE_FROM, 200))) for _ in range(10)] + \
        [frame_like(rng, int(rng.integers(knapsack.REDUCE_FROM, 200)), int(rng.integers(1, 4))) for _ in range(10)]

    def solved(v, c, g, gc, cap):
        return (knapsack.solve_grouped(v[:, 0], c[:, 0], g, gc, cap),
                knapsack.solve_choices(v, c, cap, groups=g, group_costs=gc))

    found = [solved(*instance) for instance in instances]
    real = knapsack_bounds.promising
    for forced in (lambda *a, **k: None, lambda *a, **k: real(*a, share=0.0)):
        monkeypatch.setattr(knapsack_bounds, "promising", forced)
        for instance, before in zip(instances, found):
            for now, then in zip(solved(*instance), before):
                assert np.array_equal(now, then)
