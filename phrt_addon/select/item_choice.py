"""One frame's BENEFIT decision (``benefit_selection.BenefitSelector.choose``): per (element,
effect) item, in ``EFFECTS`` order over elements, what competed, what was chosen and at what rate,
with the value and the cost it was chosen for."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..schema import EFFECTS


@dataclass
class ItemChoice:
    """One frame's decision: per effect (``EFFECTS`` order) over elements."""

    chosen: np.ndarray        # (n, 3) bool: the items traced
    eligible: np.ndarray      # (n, 3) bool: the items that competed
    value: np.ndarray         # (n, 3) expected error reduction (K included, no bonus)
    cost_ms: np.ndarray       # (n, 3) predicted ms
    per_pixel: np.ndarray     # (n, 3) the per-pixel estimate used
    capacity_ms: float        # the time the knapsack filled (T less overhead, less the margin)
    margin_ms: float
    rate: np.ndarray = None   # (n, 3) the rate each item is traced at (0: not traced)
    chosen_cost_ms: np.ndarray = None  # (n, 3) predicted ms of the chosen items at their rate
    fixed_ms: float = 0.0     # the fixed parts of the effects chosen (paid once each)
    visible: np.ndarray = None  # (n,) bool: the elements in view (None: those with an eligible item)

    @property
    def rates(self) -> dict[str, np.ndarray]:
        """Per effect name, each element's rate (``TraceStage.run(rates=...)``; 1.0 where not traced)."""
        return {effect: np.where(self.rate[:, index] > 0, self.rate[:, index], 1.0)
                for index, effect in enumerate(EFFECTS)}

    @property
    def effects(self) -> dict[str, np.ndarray]:
        """Per effect name, the elements whose effect is traced (``TraceStage.run(effects=...)``)."""
        return {effect: self.chosen[:, index] for index, effect in enumerate(EFFECTS)}

    @property
    def selected(self) -> np.ndarray:
        return self.chosen.any(axis=1)
