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
> 0 always are.  Plain numpy: the programme is one vectorised row update per item.
"""
from __future__ import annotations

import numpy as np

DEFAULT_BINS = 256
EXACT_LIMIT = 1000
CORE_ITEMS = 96
MAX_BINS = 4096


LARGE = np.finfo(np.float64).max / 4


def _finite(values, nan: float) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64).ravel()
    return np.nan_to_num(array, nan=nan, posinf=LARGE, neginf=0.0)


def _dynamic_programme(values, weights, capacity_bins) -> np.ndarray:
    """Exact 0/1 knapsack over integer ``weights`` (>= 1) within ``capacity_bins``: a mask."""
    n = len(values)
    best = np.zeros(capacity_bins + 1)
    took = np.zeros((n, capacity_bins + 1), dtype=bool)
    for index in range(n):
        weight = int(weights[index])
        if weight > capacity_bins:
            continue
        candidate = best[:capacity_bins + 1 - weight] + values[index]
        better = candidate > best[weight:]
        took[index, weight:] = better
        best[weight:] = np.where(better, candidate, best[weight:])
    chosen = np.zeros(n, dtype=bool)
    remaining = capacity_bins
    for index in range(n - 1, -1, -1):
        if took[index, remaining]:
            chosen[index] = True
            remaining -= int(weights[index])
    return chosen


def bins_for(n_items: int, bins: int = DEFAULT_BINS) -> int:
    """Bins of T for ``n_items``: at least ``bins``, and four per item (up to MAX_BINS) so that
    many small items do not lose most of T to the rounding."""
    return int(min(max(int(bins), 4 * int(n_items)), MAX_BINS))


def _binned(values, costs, capacity, bins) -> np.ndarray:
    """The exact programme over costs rounded up to bins of ``capacity``."""
    if capacity <= 0 or len(values) == 0:
        return np.zeros(len(values), dtype=bool)
    n_bins = bins_for(len(values), bins)
    # Rounded up (less a relative 1e-9 that float division adds to whole bins): a chosen set of
    # rounded cost <= n_bins has true cost <= capacity.  Divided by T first (T may be subnormal).
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        in_bins = np.nan_to_num(np.minimum(costs / capacity * n_bins, n_bins + 1.0), nan=n_bins + 1.0)
    weights = np.maximum(np.ceil(in_bins * (1.0 - 1e-9)), 1).astype(np.int64)
    return _dynamic_programme(values, weights, n_bins)


def solve(values, costs, capacity, bins: int = DEFAULT_BINS) -> np.ndarray:
    """The items (bool mask) of the largest summed value whose summed cost is <= ``capacity``."""
    values = _finite(values, nan=0.0)
    costs = _finite(costs, nan=LARGE)  # an unknown cost never fits
    if values.shape != costs.shape:
        raise ValueError(f"values and costs differ in shape: {values.shape} vs {costs.shape}")
    costs = np.maximum(costs, 0.0)
    capacity = float(np.nan_to_num(capacity, nan=0.0, posinf=np.finfo(np.float64).max / 4))
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
    up to bins of T as in :func:`solve` (never over T); exact for the rounded costs; compared
    with the best single (item, option) that fits.  ``groups`` (int per item, into
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
    capacity = float(np.nan_to_num(capacity, nan=0.0, posinf=LARGE))
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
    used_groups = np.unique(groups[rows])
    n_bins = bins_for(len(rows) + len(used_groups), bins)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):  # in bins of T (T may be subnormal)
        weights = np.nan_to_num(np.minimum(costs / capacity * n_bins, n_bins + 1.0), nan=n_bins + 1.0)
        group_weights = np.nan_to_num(np.minimum(group_costs / capacity * n_bins, n_bins + 1.0), nan=n_bins + 1.0)
    weights = np.ceil(weights * (1.0 - 1e-9)).astype(np.int64)  # 0 only for a free option
    group_weights = np.ceil(group_weights * (1.0 - 1e-9)).astype(np.int64).tolist()
    best = np.zeros(n_bins + 1)
    took = np.full((len(rows), n_bins + 1), -1, np.int8 if n_options < 127 else np.int64)
    # One row update: the table with each option taken (row o + 1 of ``table``; -inf where it
    # does not fit) against the table without (row 0), the best per bin and which option won.
    # Per group the programme runs from the table with the group's cost paid ("opened"), and the
    # group is used only where that ends better than without it.
    table = np.empty((n_options + 1, n_bins + 1))
    columns = np.arange(n_bins + 1)
    labels = np.arange(-1, n_options, dtype=took.dtype)
    row_weights = np.minimum(weights, n_bins + 1).tolist()
    row_values = values.tolist()
    row_groups = groups[rows]
    trail = []
    for group in used_groups.tolist():
        fixed = group_weights[group]
        if fixed > n_bins:
            continue
        members = np.flatnonzero(row_groups == group).tolist()
        opened = np.full(n_bins + 1, -np.inf)
        opened[fixed:] = best[:n_bins + 1 - fixed]
        for position in members:
            row = int(rows[position])
            table[0] = opened
            table[1:] = -np.inf
            for option in np.flatnonzero(usable[row]).tolist():
                weight = row_weights[row][option]
                if weight <= n_bins:
                    np.add(opened[:n_bins + 1 - weight], row_values[row][option], out=table[option + 1, weight:])
            winner = table.argmax(axis=0)
            opened = table[winner, columns]
            took[position] = labels[winner]
        use = opened > best
        trail.append((members, use, fixed))
        best = np.where(use, opened, best)
    remaining = n_bins
    for members, use, fixed in reversed(trail):
        if not use[remaining]:
            continue
        for position in reversed(members):
            option = int(took[position, remaining])
            if option >= 0:
                choice[rows[position]] = option
                remaining -= int(weights[rows[position], option])
        remaining -= fixed
    flat = np.where(usable, values, -np.inf).ravel()
    single = int(np.argmax(flat))
    if flat[single] > float(sum(values[i, o] for i, o in enumerate(choice) if o >= 0)):
        choice[:] = -1
        choice[single // n_options] = single % n_options
    return choice


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
    capacity = float(np.nan_to_num(capacity, nan=0.0, posinf=LARGE))
    chosen = np.zeros(len(values), dtype=bool)
    if capacity < 0 or len(values) == 0:
        return chosen
    total = costs + group_costs[groups] if len(groups) else costs
    useful = np.flatnonzero((values > 0) & (total <= capacity))
    if len(useful) == 0:
        return chosen
    if len(useful) > EXACT_LIMIT or capacity <= 0:
        return _grouped_by_subsets(values, costs, groups, group_costs, capacity, useful, bins)
    n_bins = bins_for(len(useful) + len(group_costs), bins)
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        def in_bins(ms):
            scaled = np.nan_to_num(np.minimum(ms / capacity * n_bins, n_bins + 1.0), nan=n_bins + 1.0)
            return np.ceil(scaled * (1.0 - 1e-9)).astype(np.int64)
        weights, group_weights = in_bins(costs[useful]), in_bins(group_costs)
    best = np.zeros(n_bins + 1)
    trail = []  # per group with useful items: (group, its items, took, opened-at mask)
    weight_of, value_of = weights.tolist(), values[useful].tolist()
    for group in np.unique(groups[useful]).tolist():
        members = np.flatnonzero(groups[useful] == group)
        fixed = int(group_weights[group])
        if fixed > n_bins:
            continue
        opened = np.full(n_bins + 1, -np.inf)
        opened[fixed:] = best[:n_bins + 1 - fixed]
        took = np.zeros((len(members), n_bins + 1), dtype=bool)
        for position, member in enumerate(members.tolist()):
            weight = weight_of[member]
            if weight > n_bins - fixed:
                continue
            candidate = opened[:n_bins + 1 - weight] + value_of[member]
            segment = opened[weight:]
            better = np.greater(candidate, segment, out=took[position, weight:])
            np.copyto(segment, candidate, where=better)
        # Opening the group pays only if it buys something: an empty open group is never better.
        use = opened > best
        trail.append((members, took, use, fixed))
        best = np.where(use, opened, best)
    remaining = n_bins
    for members, took, use, fixed in reversed(trail):
        if not use[remaining]:
            continue
        for position in range(len(members) - 1, -1, -1):
            if took[position, remaining]:
                chosen[useful[members[position]]] = True
                remaining -= int(weights[members[position]])
        remaining -= fixed
    single = useful[np.argmax(values[useful])]
    if values[single] > float(np.sum(values[chosen])):
        chosen[:] = False
        chosen[single] = True
    return chosen


SUBSET_GROUPS = 4


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

    candidates = []
    if float(group_costs[present].sum()) <= capacity or len(present) > SUBSET_GROUPS:
        paid = present
        for _ in range(len(present)):
            candidates.append(solved(paid))
            used = [g for g in paid if np.any(candidates[-1] & (groups == g))]
            if not used or used == paid:
                break
            paid = used
    else:
        candidates = [solved([g for bit, g in enumerate(present) if mask >> bit & 1])
                      for mask in range(1, 2 ** len(present))]
    chosen = max(candidates, key=lambda picked: float(values[picked].sum()))
    single = useful[np.argmax(values[useful])]
    if values[single] > float(values[chosen].sum()):
        chosen = np.zeros(len(values), dtype=bool)
        chosen[single] = True
    return chosen
