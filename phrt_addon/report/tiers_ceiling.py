"""The most any choice of rates could buy (issue 23's ceiling): an oracle over (element, effect, rate).

The oracle (``oracle.py``) traces whole elements at full rate.  Here each (element, effect)
item of a sampled frame is traced alone at every rate of ``trace.rates.RATES`` (``tools/
tiers_ceiling.py`` renders them), and :meth:`TierCandidates.choose` picks at most one rate per item,
exactly, within the frame's time for tracing: the multiple-choice knapsack solved by meet in the
middle (every combination of each half's options, the second half's best value per cost found by
binary search), exact up to ``EXACT_COMBINATIONS`` combinations a half (20 items of three
rates), ``knapsack.solve_choices`` (binned, within its bound) beyond.  The trace stage's fixed
part is paid once, as the oracle's ``FrameCandidates`` does, so ``oracle_fit.feasible_choice``
holds the chosen combination to its measured time the same way.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..select import knapsack
from .oracle import MIN_BENEFIT

EXACT_COMBINATIONS = 1 << 21  # a half's combinations at most (20 items of 3 rates: 4^10 a half)


def _half(values, costs):
    """(value, cost, picks) of every combination of one half's options (-1: the item not traced)."""
    total_value, total_cost = np.zeros(1), np.zeros(1)
    picks = np.zeros((1, 0), np.int8)
    for row_values, row_costs in zip(values, costs):
        options = np.flatnonzero(np.isfinite(row_costs) & (row_values > 0))
        option_values = np.r_[0.0, row_values[options]]
        option_costs = np.r_[0.0, row_costs[options]]
        total_value = (total_value[:, None] + option_values[None, :]).ravel()
        total_cost = (total_cost[:, None] + option_costs[None, :]).ravel()
        picks = np.concatenate([np.repeat(picks, len(option_values), axis=0),
                                np.tile(np.r_[-1, options].astype(np.int8), len(picks))[:, None]], axis=1)
    return total_value, total_cost, picks


def _middle(costs) -> int:
    """Where to split the items so the halves' numbers of combinations are as even as can be."""
    sizes = np.log(1.0 + np.count_nonzero(np.isfinite(costs), axis=1))
    cumulative = np.r_[0.0, np.cumsum(sizes)]
    return int(np.argmin(np.abs(cumulative - cumulative[-1] / 2.0)))


def _exact_middle(costs):
    """The split of the meet in the middle over ``costs`` (inf: an option never taken), None when a
    half would have more than ``EXACT_COMBINATIONS`` combinations."""
    costs = np.asarray(costs, np.float64)
    if len(costs) == 0:
        return 0
    middle = _middle(costs)
    sizes = 1.0 + np.count_nonzero(np.isfinite(costs), axis=1)
    fits = max(float(np.prod(sizes[:middle])), float(np.prod(sizes[middle:]))) <= EXACT_COMBINATIONS
    return middle if fits else None


def exact_size(costs) -> bool:
    """Whether the meet in the middle over ``costs`` is within ``EXACT_COMBINATIONS`` a half."""
    return _exact_middle(costs) is not None


def exact_choices(values, costs, capacity: float) -> np.ndarray:
    """(n,) the option index picked per item (-1: none) maximising the summed ``values`` (n, k)
    with summed ``costs`` (n, k) <= ``capacity``; among equal values the cheaper combination.
    Exact (meet in the middle) while each half has at most ``EXACT_COMBINATIONS`` combinations of
    its usable options, ``knapsack.solve_choices`` (binned, within its bound) beyond."""
    values = np.nan_to_num(np.asarray(values, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    costs = np.nan_to_num(np.asarray(costs, np.float64), nan=np.inf, posinf=np.inf, neginf=np.inf)
    n = len(values)
    picked = np.full(n, -1, np.int64)
    capacity = float(capacity)
    if n == 0 or not capacity >= 0:
        return picked
    slack = 1e-12 * capacity  # sums in another order than the caller's may differ by an ulp
    costs = np.where(costs < 0, 0.0, costs)
    costs = np.where((costs <= capacity + slack) & (values > 0), costs, np.inf)  # options that may be taken
    middle = _exact_middle(costs)
    if middle is None:
        return np.asarray(knapsack.solve_choices(values, costs, capacity), np.int64)
    value_a, cost_a, picks_a = _half(values[:middle], costs[:middle])
    value_b, cost_b, picks_b = _half(values[middle:], costs[middle:])
    order = np.lexsort((-value_b, cost_b))  # by cost, the best value first among equal costs
    value_b, cost_b, picks_b = value_b[order], cost_b[order], picks_b[order]
    best_b = np.maximum.accumulate(value_b)  # the best value of the second half within each cost
    where_best = np.zeros(len(value_b), np.int64)
    improves = np.r_[True, value_b[1:] > best_b[:-1]]
    where_best[improves] = np.flatnonzero(improves)
    where_best = np.maximum.accumulate(where_best)
    fits = cost_a <= capacity + slack
    room = capacity + slack - cost_a[fits]
    last = np.searchsorted(cost_b, room, side="right") - 1  # cost_b[0] == 0: always >= 0
    totals = value_a[fits] + best_b[last]
    spent = cost_a[fits] + cost_b[where_best[last]]
    choice = np.lexsort((spent, -totals))[0]
    first = np.flatnonzero(fits)[choice]
    picked[:middle] = picks_a[first]
    picked[middle:] = picks_b[where_best[last[choice]]]
    return picked


@dataclass
class TierCandidates:
    """The measured items of one sampled frame: ``items`` [(element, effect)], ``rates`` the options'
    rates, ``cost_ms`` / ``benefit`` (n, len(rates)) each option traced alone (its cost without the
    trace stage's fixed part ``overhead_ms``, its LDR-FLIP removed from the raster frame)."""

    frame: int
    items: list
    rates: tuple
    cost_ms: np.ndarray
    benefit: np.ndarray
    flip_raster: float
    overhead_ms: float = 0.0
    allowed: np.ndarray = field(default=None)  # (n, len(rates)) options the choice may take (None: all)

    def choose(self, capacity_ms: float) -> frozenset:
        """The best combination for ``capacity_ms`` of tracing: {(element, effect, rate)}."""
        room = float(capacity_ms) - self.overhead_ms
        if room < 0 or not self.items:
            return frozenset()
        values = np.maximum(self.benefit, MIN_BENEFIT)
        costs = np.asarray(self.cost_ms, np.float64)
        if self.allowed is not None:
            costs = np.where(self.allowed, costs, np.inf)
        picked = exact_choices(values, costs, room)
        return frozenset((*self.items[row], self.rates[option]) for row, option in enumerate(picked.tolist())
                         if option >= 0)

    def totals(self, chosen) -> tuple[float, float]:
        """(cost ms, summed benefit) of a combination; a non-empty one pays the fixed part once."""
        index = {item: row for row, item in enumerate(self.items)}
        cost = value = 0.0
        for element, effect, rate in chosen:
            row, option = index[(element, effect)], self.rates.index(rate)
            cost += float(self.cost_ms[row, option])
            value += float(max(self.benefit[row, option], MIN_BENEFIT))
        return cost + (self.overhead_ms if chosen else 0.0), value
