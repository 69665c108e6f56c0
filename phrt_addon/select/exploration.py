"""The BENEFIT selection's exploration (``benefit_selection.BenefitSelector.choose``): which
never-measured items get a bonus, how much, and which items the exploration's knapsack holds.
Plain numpy."""
from __future__ import annotations

import numpy as np


def exploration(explore: np.ndarray, allowed: np.ndarray, added: np.ndarray | None, waited: np.ndarray,
                value: np.ndarray, cost: np.ndarray, total: float, frames: int, most: int,
                fits: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(the items the exploration's knapsack holds, each item's bonus), shaped as ``explore``.

    ``explore`` (bool) the never-measured items that fit the time the kept items leave;
    ``allowed`` (bool) the items this frame may add; ``added`` (bool) those the first knapsack
    added (None: the knapsack holds every allowed item; quality tiers' multiple-choice knapsack
    is exact on fewer items, and slower); ``waited`` the frames each ``explore`` item waited (in
    its flat order); ``value`` and ``cost`` every item's (switched) value and predicted ms;
    ``fits`` (bool, every item, optional) whether it fits with its effect's unpaid fixed part.

    An item's bonus is ``total`` x min((waited + 1) / ``frames``, 1): after ``frames`` frames it
    outweighs every other item together.  At most ``most`` items get it: those that fit first,
    then those that waited longest, then the most valuable per ms; the others compete by their
    value alone.  Items that cannot fit cannot hold the places (they would, waiting ever longer):
    a frame with room traces some of the fitting ones, which leave the exploration, and the next
    waiting take their place.  Beyond ``most`` allowed items the knapsack holds only the bonus
    items and the first knapsack's adds: an item it left out with the whole room is not added in
    less (nearly always; the exact programme over 800 items cost 4-5 ms, twice a frame at 1,000
    candidates)."""
    waited = np.asarray(waited, np.float64)
    bonus = np.zeros(explore.shape)
    if len(waited) > most:
        explored = np.flatnonzero(explore.ravel())
        ratio = value.ravel()[explored] / np.maximum(cost.ravel()[explored], 1e-12)
        unfit = np.zeros(len(explored), bool) if fits is None else ~np.asarray(fits, bool).ravel()[explored]
        first = np.sort(np.lexsort((-ratio, -waited, unfit))[:most])
        explore = np.zeros(explore.shape, bool)
        explore.ravel()[explored[first]] = True
        waited = waited[first]
    bonus[explore] = total * np.minimum((waited + 1) / frames, 1.0)
    if added is not None and np.count_nonzero(allowed) > most:
        allowed = allowed & (explore | added)
    return allowed, bonus
