"""The BENEFIT selection's exploration bonus (``benefit_selection.BenefitSelector.choose``): which
never-measured items get it, and how much.  Plain numpy."""
from __future__ import annotations

import numpy as np


def exploration_bonus(explore: np.ndarray, waited: np.ndarray, value: np.ndarray, cost: np.ndarray,
                      total: float, frames: int, most: int) -> np.ndarray:
    """The bonus of each item (shaped as ``explore``) in the exploration's knapsack.

    ``explore`` (bool) the never-measured items that fit the time the kept items leave;
    ``waited`` the frames each of them waited (in ``explore``'s flat order); ``value`` and
    ``cost`` every item's (switched) value and predicted ms.  An item's bonus is ``total`` x
    min((waited + 1) / ``frames``, 1): after ``frames`` frames it outweighs every other item
    together.  At most ``most`` items get it, those that waited longest, then the most valuable
    per ms: a bound on the knapsack's work (hundreds of items of one equal bonus leave its bound
    nothing to fix), not on what may be added; the others compete by their value alone, and a
    frame more waited puts them first next time."""
    waited = np.asarray(waited, np.float64)
    bonus = np.zeros(explore.shape)
    if len(waited) > most:
        explored = np.flatnonzero(explore.ravel())
        ratio = value.ravel()[explored] / np.maximum(cost.ravel()[explored], 1e-12)
        first = np.sort(np.lexsort((-ratio, -waited))[:most])
        explore = np.zeros(explore.shape, bool)
        explore.ravel()[explored[first]] = True
        waited = waited[first]
    bonus[explore] = total * np.minimum((waited + 1) / frames, 1.0)
    return bonus
