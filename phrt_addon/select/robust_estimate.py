"""A learned quantity of the cost model (``cost_model.py``), built for the budget loop:

* cold start: the prior is used until the first measurement, which replaces it;
  until the window is full the estimate is the running median of what was seen
  (the first frame's JIT-slow raster time is voted out by the second and third);
* noise: inside a gate (ratio ``gate_ratio``) an exponential moving average in
  the log domain, which converges monotonically (no overshoot);
* outliers: an observation outside the gate is ignored;
* step changes: consecutive observations outside the gate on the same side mean
  the quantity really changed, and the estimate jumps to the median of them:
  ``confirm_up`` (2) above the gate - a cost that rose puts frames over budget,
  so at most two in a row - and ``confirm`` (3) below it - a cost that fell only
  leaves time unused.  A 10x step of the cost per ray is therefore followed
  exactly after 2 (up) or 3 (down) frames, without oscillating (the stiff case
  of the budget loop, simulated in tests/core/test_cost_model.py and
  tests/core/test_budget_loop.py);
* revision: ``revise`` divides the estimate and starts a cold start again, for a cost
  that priced every frame out and so was never measured again (``cost_model.STALE_FRAMES``).
"""
from __future__ import annotations

import math
import statistics
from collections import deque


class RobustEstimate:
    """A positive quantity (a time, a cost per ray, a ratio) tracked in the log domain.

    See the module docstring for the behaviour; the parameters:

    ``prior``        value before any measurement (must be > 0)
    ``smoothing``    EMA weight of an observation inside the gate
    ``gate_ratio``   an observation within [value / gate_ratio, value * gate_ratio] is noise
    ``confirm``      consecutive observations below the gate that are a real change
    ``confirm_up``   the same above the gate (default: ``min(2, confirm)``)
    ``window``       observations kept for the median (cold start and re-anchoring)
    ``floor``        observations in [0, floor) count as ``floor``; negative, NaN or
                     infinite observations are ignored
    """

    def __init__(self, prior: float, *, smoothing: float = 0.3, gate_ratio: float = 1.3,
                 confirm: int = 3, window: int = 5, floor: float = 0.0, confirm_up: int | None = None):
        if not (math.isfinite(prior) and prior > 0):
            raise ValueError(f"prior must be a positive finite number, not {prior!r}")
        confirm_up = min(2, confirm) if confirm_up is None else confirm_up
        if not (0.0 < smoothing <= 1.0 and gate_ratio > 1.0 and 1 <= confirm <= window
                and 1 <= confirm_up <= window):
            raise ValueError("need 0 < smoothing <= 1, gate_ratio > 1 and 1 <= confirm, confirm_up <= window")
        self._confirm_up = confirm_up
        self._log_value = math.log(prior)
        self._value = float(prior)
        self._smoothing = smoothing
        self._log_gate = math.log(gate_ratio)
        self._confirm = confirm
        self._recent = deque(maxlen=window)
        self._cold = window  # observations left in the cold start (the running median)
        self._floor = floor
        self._outside_gate = 0
        self.observations = 0

    @property
    def value(self) -> float:
        return self._value

    def update(self, observed: float) -> bool:
        """Learn from one measurement; returns False when it was unusable (ignored)."""
        try:
            observed = float(observed)
        except (TypeError, ValueError):
            return False
        if not math.isfinite(observed) or observed < 0:
            return False
        observed = max(observed, self._floor)
        if observed <= 0:
            return False
        log_observed = math.log(observed)
        self._recent.append(log_observed)
        self.observations += 1
        if self._cold > 0:
            self._cold -= 1
            # Cold start: the running median of everything seen so far.
            self._log_value = statistics.median(self._recent)
            self._value = math.exp(self._log_value)
            self._outside_gate = 0
            return True
        innovation = log_observed - self._log_value
        if abs(innovation) <= self._log_gate:
            self._log_value += self._smoothing * innovation
            self._outside_gate = 0
        else:
            side = 1 if innovation > 0 else -1
            # Consecutive observations outside the gate on one side (a change of side starts over).
            self._outside_gate = self._outside_gate + side if self._outside_gate * side > 0 else side
            needed = self._confirm_up if side > 0 else self._confirm
            if abs(self._outside_gate) >= needed:
                self._log_value = statistics.median(list(self._recent)[-needed:])
                self._outside_gate = 0
        self._value = math.exp(self._log_value)
        return True

    def revise(self, factor: float) -> None:
        """Divide the estimate by ``factor`` and start over (the next observations are a cold
        start again): what was learned is suspect (``STALE_FRAMES``)."""
        self._log_value -= math.log(factor)
        self._value = math.exp(self._log_value)
        self._recent.clear()
        self._cold = self._recent.maxlen
        self._outside_gate = 0
