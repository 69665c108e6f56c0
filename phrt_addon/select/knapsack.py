"""0/1 knapsack of the ``BENEFIT`` selection: the items worth most within the frame's time.

``solve(values, costs, capacity)`` returns the chosen items.  Costs are milliseconds; the
capacity T is split into ``bins`` equal bins and every cost is rounded *up* to whole bins, so
the chosen set's true cost never exceeds T (the rounding can only leave time unused: at most
one bin per chosen item).  Up to ``EXACT_LIMIT`` useful items the dynamic programme over the
bins is exact for the rounded costs; beyond it the items are sorted by value per ms, the
greedy prefix is kept and a *core* of ``CORE_ITEMS`` items around the greedy's first miss is
solved exactly with the time the prefix leaves (the classic core of Balas and Zemel: the
items far from the break rarely change; not a proven bound).  Either way the result is
compared with the best single item that fits (exactly, without rounding), which bounds
the loss of the rounding on a set of few large items: the returned value is at least half
of the optimum.

Items of value <= 0, or that cannot fit alone, are never chosen; items of cost 0 and value
> 0 always are.  Plain numpy: the programme is one row of three vectorised calls per item.
From ``REDUCE_FROM`` items on, :mod:`knapsack_bounds` first fixes the items every optimum takes
or leaves (a Lagrangian bound against a greedy's value), and the programme runs over the rest
only: the same choice (for the same rounded costs), at a fraction of the programme's rows.
Up to ``ENUMERATE_LIMIT`` useful items, :func:`solve_grouped` (the selection's every frame) tries
every subset instead, on the costs as they are: exact, without the bins' rounding, and a few
numpy calls on a table of at most 2 ** ENUMERATE_LIMIT rows rather than one row of calls per item
(5 and 10 items in 3 groups: 0.21 and 0.26 ms the programme, 0.05 and 0.12 the enumeration).
"""
from __future__ import annotations

import numpy as np

from . import knapsack_bounds, knapsack_greedy
from ..finite import finite

DEFAULT_BINS = 256
EXACT_LIMIT = 1000
CORE_ITEMS = 96
MAX_BINS = 4096
# Items from which the bound's reduction runs first (knapsack_bounds): below it the programme
# over every item costs less than the bound (about 0.2 ms of numpy calls either way).
REDUCE_FROM = 48
ENUMERATE_LIMIT = 10


LARGE = np.finfo(np.float64).max / 4


def _finite(values, nan: float) -> np.ndarray:
    """Flat float64, NaN as ``nan``, +inf as LARGE, -inf as 0 (no copy when all finite)."""
    return finite(values, nan=nan, posinf=LARGE, neginf=0.0).ravel()


def _number(value, nan: float) -> float:
    """A float capacity: NaN as ``nan``, +inf as LARGE (math on a scalar: nan_to_num is slow)."""
    value = float(value)
    return nan if value != value else min(value, LARGE)


def _in_bins(ms, capacity, n_bins) -> np.ndarray:
    """Costs (ms) in whole bins of ``capacity``, rounded up (less a relative 1e-9 that float
    division adds to whole bins); at most n_bins + 1 (does not fit), NaN as that too."""
    if capacity > 0 and capacity <= LARGE:  # at most 2 x n_bins before the cap: no overflow, no errstate
        capped = np.minimum(np.asarray(ms, np.float64), 2.0 * capacity)
        scaled = np.minimum(capped / capacity * n_bins, n_bins + 1.0)
    else:
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            scaled = np.minimum(np.asarray(ms, np.float64) / capacity * n_bins, n_bins + 1.0)
    if not np.isfinite(scaled).all():
        scaled = np.nan_to_num(scaled, nan=n_bins + 1.0)
    return np.ceil(scaled * (1.0 - 1e-9)).astype(np.int64)


def bins_for(n_items: int, bins: int = DEFAULT_BINS) -> int:
    """Bins of T for ``n_items``: at least ``bins``, and four per item (up to MAX_BINS) so that
    many small items do not lose most of T to the rounding."""
    return int(min(max(int(bins), 4 * int(n_items)), MAX_BINS))


def _binned(values, costs, capacity, bins) -> np.ndarray:
    """The exact programme over costs rounded up to bins of ``capacity``."""
    if capacity <= 0 or len(values) == 0:
        return np.zeros(len(values), dtype=bool)
    n_bins = bins_for(len(values), bins)
    # Rounded up: a chosen set of rounded cost <= n_bins has true cost <= capacity.
    weights = np.maximum(_in_bins(costs, capacity, n_bins), 1)
    return _zero_one(np.asarray(values, np.float64), weights, np.zeros(len(values), np.int64), [0], n_bins)


def solve(values, costs, capacity, bins: int = DEFAULT_BINS) -> np.ndarray:
    """The items (bool mask) of the largest summed value whose summed cost is <= ``capacity``."""
    values = _finite(values, nan=0.0)
    costs = _finite(costs, nan=LARGE)  # an unknown cost never fits
    if values.shape != costs.shape:
        raise ValueError(f"values and costs differ in shape: {values.shape} vs {costs.shape}")
    costs = np.maximum(costs, 0.0)
    capacity = _number(capacity, nan=0.0)
    chosen = np.zeros(len(values), dtype=bool)
    if capacity < 0 or len(values) == 0:
        return chosen
    free = (costs == 0) & (values > 0)
    chosen |= free
    useful = np.flatnonzero((values > 0) & (costs > 0) & (costs <= capacity))
    if len(useful) == 0 or capacity <= 0:
        return chosen
    picked = np.zeros(len(useful), dtype=bool)
    if len(useful) <= EXACT_LIMIT:
        picked = _binned(values[useful], costs[useful], capacity, bins)
    else:
        # The ratio greedy's prefix (true costs) up to a core around its first miss, then the core.
        order = np.lexsort((useful, -(values[useful] / costs[useful])))
        prefix = int(np.searchsorted(np.cumsum(costs[useful][order]), capacity, side="right"))
        start = max(prefix - CORE_ITEMS // 2, 0)
        core = order[start:start + CORE_ITEMS]
        fixed = order[:start]
        picked[fixed] = True
        left = capacity - float(np.sum(costs[useful][fixed]))
        picked[core] = _binned(values[useful][core], costs[useful][core], left, bins)
    fits_alone = useful[costs[useful] <= capacity]
    single = fits_alone[np.argmax(values[fits_alone])]
    if values[single] > float(np.sum(values[useful][picked])):
        chosen[single] = True
    else:
        chosen[useful[picked]] = True
    return chosen


def solve_choices(values, costs, capacity, bins: int = DEFAULT_BINS, groups=None, group_costs=None) -> np.ndarray:
    """Multiple-choice knapsack: per item (row) at most one option (column), the largest summed
    value within ``capacity``.  Returns the chosen option per item, -1 for none.  Costs rounded
    up to bins of T as in :func:`solve` (never over T); exact for the rounded costs up to
    ``EXACT_LIMIT`` items that may be chosen, beyond them the greedy on the linear relaxation's
    increments (:mod:`knapsack_greedy`, true costs); compared with the best single (item, option)
    that fits.  ``groups`` (int per item, into
    ``group_costs``): a group's cost is paid once if any of its items is chosen, as in
    :func:`solve_grouped` (an effect's fixed work)."""
    values = np.atleast_2d(_finite(values, nan=0.0).reshape(np.shape(values)))
    costs = np.atleast_2d(_finite(costs, nan=LARGE).reshape(np.shape(values)))
    n_items, n_options = values.shape
    groups = np.zeros(n_items, np.int64) if groups is None else np.asarray(groups, np.int64).ravel()
    group_costs = np.zeros(1) if group_costs is None else np.maximum(_finite(group_costs, nan=LARGE), 0.0)
    if groups.shape != (n_items,) or (n_items and (groups.min() < 0 or groups.max() >= len(group_costs))):
        raise ValueError("groups must give each item an index into group_costs")
    choice = np.full(n_items, -1, np.int64)
    capacity = _number(capacity, nan=0.0)
    if n_items == 0 or n_options == 0 or capacity < 0:
        return choice
    free = np.where((costs <= 0) & (values > 0) & (group_costs[groups] <= 0)[:, None], values, -np.inf)
    free_choice = np.where(np.isfinite(free.max(axis=1)), np.argmax(free, axis=1), -1).astype(np.int64)
    if capacity == 0:  # only free options: the most valuable of each item
        return free_choice
    usable = (values > 0) & (costs + group_costs[groups][:, None] <= capacity)
    rows = np.flatnonzero(usable.any(axis=1))
    if len(rows) == 0:
        return choice
    if len(rows) > EXACT_LIMIT:  # beyond the programme's reach in a frame: the increments' greedy
        choice[rows] = knapsack_greedy.grouped_greedy(values[rows], costs[rows], usable[rows], groups[rows],
                                                      group_costs, capacity)
    else:
        used_groups = np.unique(groups[rows])
        n_bins = bins_for(len(rows) + len(used_groups), bins)
        weights = _in_bins(costs, capacity, n_bins)  # 0 only for a free option (T may be subnormal)
        group_weights = _in_bins(group_costs, capacity, n_bins).tolist()
        choice[rows] = _programme(values[rows], weights[rows], usable[rows], groups[rows], group_weights, n_bins)
    flat = np.where(usable, values, -np.inf).ravel()
    single = int(np.argmax(flat))
    taken = choice >= 0
    if flat[single] > float(values[np.flatnonzero(taken), choice[taken]].sum()):
        choice[:] = -1
        choice[single // n_options] = single % n_options
    return choice


def _choices_programme(values, weights, usable, groups, group_weights, capacity_bins) -> np.ndarray:
    """The exact multiple-choice programme over whole-bin ``weights`` (rows x options) within
    ``capacity_bins``: the option per row, -1 for none.

    Per group, one table row per item: the best value at each bin with the items so far (the
    group's weight paid at the start), each usable option two numpy calls.  The trace back finds
    where a row gained on the one before and which option gave that value (the first that did:
    the same sums in the same order, so equal to the bit)."""
    n_rows, n_options = values.shape
    choice = np.full(n_rows, -1, np.int64)
    if capacity_bins < 0 or n_rows == 0:
        return choice
    size = capacity_bins + 1
    best = np.zeros(size)
    shifted = np.empty(size)
    row_weights, row_values = np.asarray(weights).tolist(), np.asarray(values).tolist()
    fits = np.asarray(usable, bool) & (np.asarray(weights) <= capacity_bins)
    if n_options == 1:  # the 0/1 programme: one shared list per answer
        only, none = [0], []
        row_options = [only if flag else none for flag in fits[:, 0].tolist()]
    else:
        row_options = [[option for option, flag in enumerate(flags) if flag] for flags in fits.tolist()]
    groups = np.asarray(groups)
    trail = []  # per group with items: (its items, its table, opened-at mask, its fixed bins)
    for group in np.unique(groups).tolist():
        fixed = int(group_weights[group])
        # A row without a usable option changes nothing (nor does a group without one: best is
        # non-decreasing in the bins, and the group's weight only shifts it right).
        members = np.flatnonzero((groups == group) & fits.any(axis=1)).tolist()
        if fixed > capacity_bins or not members:
            continue
        table = np.empty((len(members) + 1, size))
        table[0, :fixed] = -np.inf
        table[0, fixed:] = best[:size - fixed]
        rows = list(table)  # the rows' views, made at once
        for position, member in enumerate(members):
            before, row = rows[position], rows[position + 1]
            row[:] = before
            for option in row_options[member]:
                weight = row_weights[member][option]
                gained = shifted[:size - weight]
                np.add(before[:size - weight], row_values[member][option], out=gained)
                np.maximum(row[weight:], gained, out=row[weight:])
        opened = table[-1]
        use = opened > best
        trail.append((members, table, use, fixed))
        best = np.where(use, opened, best)
    remaining = capacity_bins
    for members, table, use, fixed in reversed(trail):
        if not use[remaining]:
            continue
        column = table[:, remaining].tolist()  # the values at the bins left (again after each take)
        for position in range(len(members) - 1, -1, -1):
            now = column[position + 1]
            if not now > column[position]:
                continue
            member = members[position]
            for option in row_options[member]:
                weight = row_weights[member][option]
                if weight <= remaining and float(table[position, remaining - weight]) + row_values[member][option] == now:
                    choice[member] = option
                    remaining -= weight
                    column = table[:position + 1, remaining].tolist()
                    break
        remaining -= fixed
    return choice


def _programme(values, weights, usable, groups, group_weights, capacity_bins) -> np.ndarray:
    """:func:`_choices_programme`, from ``REDUCE_FROM`` rows after :func:`knapsack_bounds.reduce`
    (when :func:`~knapsack_bounds.promising`): the rows every optimum fixes, then the programme
    over the free rows within the bins the fixed ones leave (their groups paid).  The same choice
    as the programme over every row."""
    masked = np.where(usable, values, -np.inf) if len(values) >= REDUCE_FROM else None
    ratio = None if masked is None else knapsack_bounds.promising(masked, weights, capacity_bins)
    if ratio is not None:
        group_array = np.asarray(group_weights, np.float64)
        fixed = knapsack_bounds.reduce(masked, weights, groups, group_array, capacity_bins, ratio)
        free = fixed == knapsack_bounds.FREE
        forced = np.flatnonzero(fixed >= 0)
        opened = np.unique(groups[forced])
        left = capacity_bins - int(weights[forced, fixed[forced]].sum()) - int(group_array[opened].sum())
        if not free.all() and left >= 0:  # left < 0 cannot happen for an exact bound
            still_due = np.array(group_weights, np.int64)
            still_due[opened] = 0
            choice = np.where(fixed >= 0, fixed, -1)
            rows = np.flatnonzero(free)
            choice[rows] = _choices_programme(values[rows], weights[rows], usable[rows], groups[rows], still_due,
                                              left)
            return choice
    return _choices_programme(values, weights, usable, groups, group_weights, capacity_bins)


def _zero_one(values, weights, groups, group_weights, capacity_bins) -> np.ndarray:
    """The 0/1 grouped programme (a mask): :func:`_programme` with one option per item."""
    return _programme(values[:, None], np.asarray(weights)[:, None], np.ones((len(values), 1), bool),
                      np.asarray(groups, np.int64), group_weights, capacity_bins) >= 0


def solve_grouped(values, costs, groups, group_costs, capacity, bins: int = DEFAULT_BINS) -> np.ndarray:
    """:func:`solve` where each item belongs to a group (``groups``: int per item, an index into
    ``group_costs``) and a group's cost is paid once if any of its items is chosen (an effect's
    fixed work: the shadow regions of the frame's pixels).  One dynamic programme whose state per
    group is open (its cost paid) or not: exact for the rounded costs up to ``EXACT_LIMIT`` items;
    beyond it :func:`solve` (its core) for each subset of up to ``SUBSET_GROUPS`` groups paid for.
    Compared with the best single item that fits with its group's cost."""
    values = _finite(values, nan=0.0)
    costs = np.maximum(_finite(costs, nan=LARGE), 0.0)
    groups = np.asarray(groups, np.int64).ravel()
    group_costs = np.maximum(_finite(group_costs, nan=LARGE), 0.0)
    if not (values.shape == costs.shape == groups.shape):
        raise ValueError(f"values, costs and groups differ in shape: {values.shape}, {costs.shape}, {groups.shape}")
    if len(groups) and (groups.min() < 0 or groups.max() >= len(group_costs)):
        raise ValueError("a group index is outside group_costs")
    capacity = _number(capacity, nan=0.0)
    chosen = np.zeros(len(values), dtype=bool)
    if capacity < 0 or len(values) == 0:
        return chosen
    total = costs + group_costs[groups] if len(groups) else costs
    useful = np.flatnonzero((values > 0) & (total <= capacity))
    if len(useful) == 0:
        return chosen
    if len(useful) <= ENUMERATE_LIMIT:
        chosen[useful[_enumerated(values[useful], costs[useful], groups[useful], group_costs, capacity)]] = True
        return chosen
    if len(useful) > EXACT_LIMIT or capacity <= 0:
        return _grouped_by_subsets(values, costs, groups, group_costs, capacity, useful, bins)
    n_bins = bins_for(len(useful) + len(group_costs), bins)
    weights, group_weights = _in_bins(costs[useful], capacity, n_bins), _in_bins(group_costs, capacity, n_bins)
    chosen[useful[_zero_one(values[useful], weights, groups[useful], group_weights, n_bins)]] = True
    single = useful[np.argmax(values[useful])]
    if values[single] > float(np.sum(values[chosen])):
        chosen[:] = False
        chosen[single] = True
    return chosen


def _enumerated(values, costs, groups, group_costs, capacity) -> np.ndarray:
    """The mask of the most valuable subset of a few items whose costs and opened groups' costs
    fit ``capacity`` (exact; of equal values the cheapest)."""
    n = len(values)
    subsets = ((np.arange(1 << n)[:, None] >> np.arange(n)) & 1).astype(bool)  # every subset, one a row
    member = np.zeros((n, len(group_costs)))
    member[np.arange(n), groups] = 1.0
    opened = (subsets @ member) > 0
    with np.errstate(over="ignore", invalid="ignore"):  # LARGE values and costs: inf sums
        spent = subsets @ costs + opened @ group_costs
        worth = subsets @ values
    fits = np.flatnonzero(spent <= capacity)  # the empty subset always fits
    row = fits[np.lexsort((spent[fits], -worth[fits]))[0]]
    # A free item (no cost, its group paid or free) is always taken, even when its value is lost in
    # the sum's rounding beside a large one.
    free = (values > 0) & (costs == 0) & ((group_costs[groups] == 0) | opened[row][groups])
    return subsets[row] | free


SUBSET_GROUPS = knapsack_greedy.SUBSET_GROUPS


def _grouped_by_subsets(values, costs, groups, group_costs, capacity, useful, bins) -> np.ndarray:
    """Beyond EXACT_LIMIT items: every group with a useful item paid for and :func:`solve` over
    the rest, again without the groups it left unused (their cost returned to T); only when the
    groups' costs together exceed T, each subset of the groups (up to SUBSET_GROUPS of them) in
    turn.  The best-valued, then the single-item guard."""
    present = np.unique(groups[useful]).tolist()

    def solved(paid):
        picked = np.zeros(len(values), dtype=bool)
        members = useful[np.isin(groups[useful], paid)]
        left = capacity - float(group_costs[paid].sum())
        if left >= 0 and len(members):  # at 0 the free items (solve takes them)
            picked[members] = solve(values[members], costs[members], left, bins)
        return picked

    candidates = knapsack_greedy.groups_paid(present, group_costs, capacity, solved,
                                             lambda picked, paid: [g for g in paid if np.any(picked & (groups == g))])
    chosen = max(candidates, key=lambda picked: float(values[picked].sum()))
    single = useful[np.argmax(values[useful])]
    if values[single] > float(values[chosen].sum()):
        chosen = np.zeros(len(values), dtype=bool)
        chosen[single] = True
    return chosen
