"""Exact reduction of the ``BENEFIT`` knapsacks: the choices every optimum shares are fixed
before the dynamic programme, which then runs over the other items only.

The programme costs one row update per item.  Most items of a frame are clearly in or clearly
out (their value per ms far from the break); only the few near it need the programme.

The bound is the Lagrangian relaxation of the time constraint.  For any multiplier r >= 0 and
any feasible choice (spent <= C), value <= value + r * (C - spent), so

    value <= L(r) = r*C + sum over groups g of max(0, -r*f_g + sum over items i of g of m_i),
    m_i = max(0, max over options o of (v_io - r*w_io)),

with f_g a group's fixed cost (paid once if any item of g is chosen).  Forcing one item to
one choice (an option, or off) changes only its group's term.  If that forced bound is below
the value of a choice known to be feasible (a greedy), no optimum makes that choice.  An item
with all but one choice excluded is fixed to the one left.  The reduction is exact: the
programme over the free items, within the time the fixed ones leave, finds the optimum of the
whole instance for the same rounded costs (ties aside).  Costs are whole bins here, as in the
programme.  Plain numpy, apart from one short loop in the greedy.
"""
from __future__ import annotations

import numpy as np

FREE = -2  # the item's choice is left to the programme
OFF = -1

# Multipliers tried around the break ratio of the relaxation (L is convex in r; the smallest wins).
_SCALES = np.array([0.0, 0.5, 0.8, 0.9, 1.0, 1.1, 1.25, 1.6, 2.5])


def _break(values, weights, capacity) -> tuple[float, float]:
    """(value per bin, bins of T left) at the (item, option) where a greedy by value per bin first
    overflows T, ignoring groups and the one-option rule ((0, 0) when everything fits)."""
    usable = np.isfinite(values) & (values > 0) & (weights > 0)
    ratio = values[usable] / weights[usable]
    order = np.argsort(-ratio, kind="stable")
    spent = np.cumsum(weights[usable][order])
    at = int(np.searchsorted(spent, capacity, side="right"))
    if at >= len(order):
        return 0.0, 0.0
    return float(ratio[order][at]), float(capacity) - (float(spent[at - 1]) if at else 0.0)


def promising(values, weights, capacity, share: float = 0.25) -> float | None:
    """Whether :func:`reduce` can be expected to fix at least ``share`` of the items, from one sort.

    An item is fixed only when its reduced value (value - r * bins, its best option) is further
    from 0 than the bound's gap L(r) - lower.  At the break ratio r0 the bound less the greedy
    prefix's value is r0 x the bins the prefix leaves (Dantzig's bound): the gap is about that
    (at most, without the effects' fixed parts).
    Items of nearly equal value (the exploration's bonuses: the whole frame's value each) make that
    gap one item wide, and the reduction fixed 0 of 89 items while costing more than the
    programme it was to shorten.  A guess either way, never a different answer: the reduction is
    exact.  Returns the break ratio (for :func:`reduce`) when promising, else None."""
    r0, left = _break(values, weights, capacity)
    if r0 <= 0.0:  # everything fits: the reduction fixes every item at once
        return r0
    reduced = np.where(np.isfinite(values), values - r0 * weights, -np.inf).max(axis=-1)
    return r0 if np.count_nonzero(np.abs(reduced) > r0 * left) >= share * len(reduced) else None


def _terms(values, weights, groups, group_weights, multiplier):
    """Per item (n, o) reduced values, m per item, group sums and terms at ``multiplier`` (arrays of
    multipliers: one leading axis per multiplier)."""
    r = np.asarray(multiplier, np.float64)[..., None, None]
    # values are finite or -inf (unusable), weights finite, r >= 0 finite: no invalid operation
    reduced = np.where(np.isfinite(values), values - r * weights, -np.inf)
    best = np.maximum(reduced.max(axis=-1), 0.0)
    n_groups = len(group_weights)
    if best.ndim == 1:
        sums = np.bincount(groups, best, minlength=n_groups)
    else:  # one bincount for every multiplier: row k's groups offset by k * n_groups
        offsets = (np.arange(len(best)) * n_groups)[:, None] + groups[None, :]
        sums = np.bincount(offsets.ravel(), best.ravel(), minlength=len(best) * n_groups).reshape(len(best), -1)
    paid = r[..., 0] * group_weights
    return reduced, best, sums, paid


def bound(values, weights, groups, group_weights, capacity, multiplier) -> np.ndarray:
    """L(r) for each multiplier: an upper bound on the value of any choice within ``capacity``."""
    multiplier = np.atleast_1d(np.asarray(multiplier, np.float64))
    _, _, sums, paid = _terms(values, weights, groups, group_weights, multiplier)
    return multiplier * capacity + np.maximum(sums - paid, 0.0).sum(axis=-1)


def greedy(values, weights, groups, group_weights, capacity, multiplier=None) -> tuple[float, np.ndarray]:
    """A feasible choice and its value: (item, option) pairs by value per bin (``multiplier`` r:
    by value - r * bins, each item's best option at r first), each taken if its item has none yet
    and it fits with its group's weight (paid once); the best single pair if better.
    Returns (value, option per item, -1 for none)."""
    n, n_options = values.shape
    choice = np.full(n, OFF, np.int64)
    usable = np.isfinite(values) & (values > 0) & (weights + group_weights[groups][:, None] <= capacity)
    flat = np.flatnonzero(usable.ravel())
    if len(flat) == 0:
        return 0.0, choice
    value, weight = values.ravel()[flat], weights.ravel()[flat]
    key = -value / np.maximum(weight, 1e-300) if multiplier is None else -(value - multiplier * weight)
    order = flat[np.lexsort((flat, key))]
    items, options = np.divmod(order, n_options)
    group_of = groups[items]
    # The prefix that fits whole (each item's first pair, each group's weight at its first pair)
    # at once; then the pairs after it one by one, only those that can still fit.
    first = np.zeros(len(order), bool)
    first[np.unique(items, return_index=True)[1]] = True
    opens = np.zeros(len(order), bool)
    heads = np.flatnonzero(first)
    opens[heads[np.unique(group_of[heads], return_index=True)[1]]] = True
    need = np.where(first, weights.ravel()[order] + np.where(opens, group_weights[group_of], 0.0), 0.0)
    prefix = int(np.searchsorted(np.cumsum(need), capacity, side="right"))
    taken = first[:prefix]
    choice[items[:prefix][taken]] = options[:prefix][taken]
    left = float(capacity) - float(need[:prefix].sum())
    total = float(values.ravel()[order[:prefix][taken]].sum())
    opened = set(group_of[:prefix].tolist())
    later = np.flatnonzero(weights.ravel()[order[prefix:]] <= left) + prefix
    later = later[choice[items[later]] == OFF]  # an item of the prefix takes no second option
    group_weight = group_weights.tolist()
    taken_items = set()
    for item, group, weight, value, option in zip(items[later].tolist(), group_of[later].tolist(),
                                                  weights.ravel()[order[later]].tolist(),
                                                  values.ravel()[order[later]].tolist(), options[later].tolist()):
        due = weight + (0.0 if group in opened else group_weight[group])
        if due <= left and item not in taken_items:
            taken_items.add(item)
            choice[item] = option
            opened.add(group)
            left -= due
            total += value
    single = int(flat[np.argmax(values.ravel()[flat])])
    if values.ravel()[single] > total:
        choice[:] = OFF
        choice[single // n_options] = single % n_options
        total = float(values.ravel()[single])
    return total, choice


def best_multiplier(values, weights, groups, group_weights, capacity, break_ratio=None) -> float:
    """The r >= 0 of the smallest bound L(r) among scales of the break ratio (L is convex in r).
    With one option per item (0/1) the break ratio is the optimum but for the groups' weights: one
    grid; with several options a second, finer grid between the neighbours of the best."""
    ratio = _break(values, weights, capacity)[0] if break_ratio is None else float(break_ratio)
    tried = np.unique(ratio * _SCALES)
    at = int(np.argmin(bound(values, weights, groups, group_weights, capacity, tried)))
    if values.shape[1] == 1:
        return float(tried[at])
    finer = np.linspace(tried[max(at - 1, 0)], tried[min(at + 1, len(tried) - 1)], 16)
    return float(finer[np.argmin(bound(values, weights, groups, group_weights, capacity, finer))])


def reduce(values, weights, groups, group_weights, capacity, break_ratio=None) -> np.ndarray:
    """:func:`fix` with its own lower bound: the greedy by value per bin, and with several options
    per item the better of it and the greedy at the bound's multiplier (which takes each item's
    best option at r: the ratio greedy takes the cheapest rates first and cannot upgrade them).
    ``break_ratio``: :func:`promising`'s, when it was asked first (the same sort)."""
    values = np.asarray(values, np.float64)
    weights = np.asarray(weights, np.float64)
    group_weights = np.asarray(group_weights, np.float64)
    if values.shape[0] == 0:
        return np.full(0, FREE, np.int64)
    r = best_multiplier(values, weights, groups, group_weights, capacity, break_ratio)
    lower = greedy(values, weights, groups, group_weights, capacity)[0]
    if values.shape[1] > 1:
        lower = max(lower, greedy(values, weights, groups, group_weights, capacity, r)[0])
    return fix(values, weights, groups, group_weights, capacity, lower, r)


def fix(values, weights, groups, group_weights, capacity, lower, r=None) -> np.ndarray:
    """The choice every optimum makes per item: ``OFF``, an option index, or ``FREE`` (left to the
    programme).  ``values``/``weights``: (n, options), weights in whole bins, an unusable option's
    value -inf; ``groups``: group per item; ``group_weights``: bins per group; ``lower``: the value
    of a feasible choice."""
    values = np.asarray(values, np.float64)
    weights = np.asarray(weights, np.float64)
    group_weights = np.asarray(group_weights, np.float64)
    n = values.shape[0]
    result = np.full(n, FREE, np.int64)
    if n == 0 or not np.isfinite(lower):
        return result
    r = best_multiplier(values, weights, groups, group_weights, capacity) if r is None else float(r)
    reduced, best, sums, paid = _terms(values, weights, groups, group_weights, r)
    terms = np.maximum(sums - paid, 0.0)
    total = r * capacity + terms.sum()
    base = total - terms[groups]
    rest = sums[groups] - best - paid[groups]  # the group's sum without the item, less its fixed part
    limit = lower - 1e-9 * (abs(total) + abs(lower) + 1.0)  # float sums: never exclude an optimum
    alive_off = base + np.maximum(rest, 0.0) >= limit
    alive = base[:, None] + rest[:, None] + reduced >= limit  # -inf (unusable) is never alive
    count = alive_off.astype(np.int64) + alive.sum(axis=1)
    single = count == 1
    result[single & alive_off] = OFF
    only = single & ~alive_off
    result[only] = np.argmax(alive[only], axis=1)
    return result
