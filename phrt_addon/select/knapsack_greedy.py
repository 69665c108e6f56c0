"""The multiple-choice knapsack beyond ``knapsack.EXACT_LIMIT`` rows (``knapsack.solve_choices``
with quality tiers on a scene of thousands of items): the greedy on the linear relaxation's
increments, plain numpy, O(options log options).

Per row (an item), its usable options with the empty choice form the upper convex hull of
(cost, value); walking a row's hull, each step is an *increment* (more cost, more value) of
falling value per ms.  The linear relaxation's optimum takes increments in order of value per
ms across all rows until T is full (Sinha and Zoltners); here every increment that still fits
and is the next of its row is taken, and a row whose increment did not fit takes no further
one.  Without the groups' costs, and with the best single option that fits (``solve_choices``
compares it), the result is at least half of the optimum: the relaxation's optimum is at most
the increments taken before the first miss plus that missed increment, whose row's option is a
single option that fits.  With them there is no such bound (the groups are paid all, then only
those used: a group left out would not be tried).
Costs as they are (no bins): never over T.  A group's cost (an effect's fixed part) is paid once
if any of its rows is chosen: every group with a usable option is paid first, then the groups
left unused are returned to T and the rows solved again; when the groups together do not fit T,
each subset of them (up to ``SUBSET_GROUPS``) in turn, the best kept.  The exact programme
(``knapsack._programme``) at 3,000 rows of 3 options took 0.5-0.9 s a frame on this machine.
"""
from __future__ import annotations

import numpy as np

SUBSET_GROUPS = 4


def _hull_increments(values, costs, usable):
    """Per row, the increments of its upper convex hull from (0, 0), vectorised over rows (one
    pass per option): arrays (row, option, cost step, value step, position on the row's hull)."""
    n_rows, n_options = values.shape
    # By cost, of equal costs the more valuable first (a free option worth more must not be dropped
    # for a free one worth less: both have an infinite slope, and the first is taken).
    by_cost = np.lexsort((-np.where(usable, values, -np.inf), np.where(usable, costs, np.inf)), axis=1)
    cost = np.take_along_axis(costs, by_cost, axis=1)
    value = np.take_along_axis(values, by_cost, axis=1)
    alive = np.take_along_axis(usable, by_cost, axis=1)
    at_cost, at_value = np.zeros(n_rows), np.zeros(n_rows)
    parts = []
    everyone = np.arange(n_rows)
    for step in range(n_options):
        rise = value - at_value[:, None]
        run = np.maximum(cost - at_cost[:, None], 0.0)
        ok = alive & (rise > 0)
        if not ok.any():
            break
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            slope = np.where(ok, np.where(run > 0, rise / run, np.inf), -np.inf)
        best = np.argmax(slope, axis=1)  # the steepest; of equal slopes the cheaper
        has = ok.any(axis=1)
        rows = everyone[has]
        picked = best[has]
        parts.append((rows, by_cost[rows, picked], cost[rows, picked] - at_cost[rows],
                      value[rows, picked] - at_value[rows], np.full(len(rows), step)))
        at_cost[rows], at_value[rows] = cost[rows, picked], value[rows, picked]
        alive &= (cost > at_cost[:, None]) & (value > at_value[:, None])
    if not parts:
        empty = np.zeros(0, np.int64)
        return empty, empty, np.zeros(0), np.zeros(0), empty
    rows, options, dc, dv, steps = (np.concatenate(column) for column in zip(*parts))
    return rows.astype(np.int64), options.astype(np.int64), np.maximum(dc, 0.0), dv, steps.astype(np.int64)


def greedy_choices(values, costs, usable, capacity) -> np.ndarray:
    """The option per row (-1: none) by the increments' greedy within ``capacity`` (true costs)."""
    values, costs = np.asarray(values, np.float64), np.asarray(costs, np.float64)
    usable = np.asarray(usable, bool) & (values > 0) & (costs <= capacity)
    choice = np.full(values.shape[0], -1, np.int64)
    if capacity < 0 or not usable.any():
        return choice
    rows, options, dc, dv, step = _hull_increments(values, costs, usable)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        ratio = np.where(dc > 0, dv / dc, np.inf)
    # A hull's steps fall in value per ms; rounding may raise a later step's a hair above an earlier
    # one's, which would take it first and charge only its own step: clamp to the step before.
    before = np.full(values.shape[0], np.inf)
    for position in range(int(step.max()) + 1 if len(step) else 0):
        at = step == position
        ratio[at] = np.minimum(ratio[at], before[rows[at]])
        before[rows[at]] = ratio[at]
    order = np.lexsort((step, rows, -ratio))  # by value per ms; a row's steps in their order
    # The relaxation's prefix: every increment before the first that does not fit (a row's steps
    # come in their order, so each row's last increment in it is its option).
    spent = np.cumsum(dc[order])
    prefix = int(np.searchsorted(spent, capacity, side="right"))
    taken = order[:prefix]
    choice[rows[taken]] = options[taken]  # in order: a row's later step overwrites its earlier one
    level = np.zeros(values.shape[0], np.int64)
    np.add.at(level, rows[taken], 1)
    left = float(capacity) - (float(spent[prefix - 1]) if prefix else 0.0)
    # Then each increment that still fits and is the next of its row; a row whose increment did not
    # fit takes none after it.  Only increments no larger than the time left can be taken.
    closed = np.zeros(values.shape[0], bool)
    rest = order[prefix:]
    for k in rest[dc[rest] <= left].tolist() if left > 0 else []:
        row = int(rows[k])
        if closed[row] or level[row] != step[k]:
            continue
        if dc[k] <= left:
            left -= float(dc[k])
            level[row] += 1
            choice[row] = options[k]
        else:
            closed[row] = True
    return choice


def grouped_greedy(values, costs, usable, groups, group_costs, capacity) -> np.ndarray:
    """:func:`greedy_choices` where each row belongs to a group whose cost is paid once if any of
    its rows is chosen (see the module's docstring)."""
    values, costs = np.asarray(values, np.float64), np.asarray(costs, np.float64)
    usable = np.asarray(usable, bool)
    groups, group_costs = np.asarray(groups, np.int64), np.asarray(group_costs, np.float64)
    present = np.unique(groups[usable.any(axis=1)]).tolist()

    def solved(paid):
        choice = np.full(len(values), -1, np.int64)
        left = float(capacity) - float(group_costs[paid].sum())
        members = np.flatnonzero(np.isin(groups, paid))
        if left >= 0 and len(members):
            choice[members] = greedy_choices(values[members], costs[members], usable[members], left)
        return choice

    def worth(choice):
        picked = choice >= 0
        return float(values[np.flatnonzero(picked), choice[picked]].sum())

    candidates = groups_paid(present, group_costs, capacity, solved,
                             lambda choice, paid: [g for g in paid if np.any((choice >= 0) & (groups == g))])
    return max(candidates, key=worth) if candidates else np.full(len(values), -1, np.int64)


def groups_paid(present, group_costs, capacity, solved, used_of) -> list:
    """The choices tried for groups whose cost is paid once (``knapsack.solve_grouped`` beyond its
    programme, :func:`grouped_greedy`): ``solved(paid groups)`` with every group ``present`` paid,
    then again with only those ``used_of(choice, paid)`` while that drops some; when the groups
    together do not fit ``capacity``, each non-empty subset of them (up to SUBSET_GROUPS groups)."""
    candidates = []
    if float(group_costs[present].sum()) <= capacity or len(present) > SUBSET_GROUPS:
        paid = present
        for _ in range(len(present)):
            candidates.append(solved(paid))
            used = used_of(candidates[-1], paid)
            if not used or used == paid:
                break
            paid = used
    else:
        candidates = [solved([g for bit, g in enumerate(present) if mask >> bit & 1])
                      for mask in range(1, 2 ** len(present))]
    return candidates
