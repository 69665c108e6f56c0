"""What the frame's time allows the BENEFIT selection (``benefit_selection.BenefitSelector``):
the margin, the steady time left and the aim on the frame time.  Ratios and frame counts, no
milliseconds: the same on a machine twice as fast.

The margin
    The time left is reduced by the 80th percentile of (measured - predicted) trace ms over
    the traced frames among the last ``MARGIN_FRAMES`` frames whose prediction was informed
    (the fixed overhead and every chosen effect measured before; the median below
    ``MARGIN_MIN_SAMPLES`` such frames; none without: an effect never measured is charged 1.5x
    its prior; within -half..half of the time left): a prediction found too low is not
    believed again after a few cheap frames, one found too high lets the time be filled.  The
    margin is additive (the trace stage's fixed work per light and layer is what the per-item
    costs miss, whatever is chosen), and it ages by frames, so a frame that traces nothing
    cannot freeze it.
The steady time left
    An item not traced last frame must fit (with ``benefit_selection.ADD_SLACK``) in the
    ``STEADY_QUANTILE``-th percentile of the time left over the last ``STEADY_FRAMES`` frames
    (this one included), not in this frame's peak.
The measurement's cost
    Measuring what the traced items changed (the GPU's change targets, their read-back and the
    per-item sums) costs a traced frame some ms the knapsack does not plan: the median over the
    last ``MEASURE_SAMPLES`` traced frames that measured, less that of those that did not
    (``MeasureCost``).  A frame measures when the time its items leave pays for it, or when its
    items were not measured for long (``benefit_selection.BenefitSelector.wants_measurement``).
The aim
    What the time left cannot see (the raster half's and the composite's own noise, the trace
    stage's spread around its prediction) makes frames of fixed work swing: a raster-only or
    a fully ray traced replay's p95 is 1.24-1.41x its median (arcade, atrium path1, showcase,
    320x240).  The knapsack fills ``aim`` x the budget, less the stages' predictions; ``aim``
    tracks, by stochastic approximation (Robbins-Monro), the share of frames that end over
    ``AIM_OVER`` x the budget, towards ``AIM_SHARE``: each frame over lowers log(aim) by
    ``AIM_STEP`` x (1 - AIM_SHARE), each frame within raises it by AIM_STEP x AIM_SHARE.  A run
    whose frames keep within uses more than the budget's nominal time left; one that overruns
    uses less; a frame that traced nothing and ended over anyway is not counted.  Ratios, no
    milliseconds: the same on a machine twice as fast.
"""
from __future__ import annotations

from collections import deque

import numpy as np

STEADY_FRAMES = 8
STEADY_QUANTILE = 25
MARGIN_FRAMES = 20
MARGIN_QUANTILE = 80
MARGIN_MIN_SAMPLES = 5
# The aim: p95 frame time at AIM_OVER x the budget, half the 1.10 allowance (a run of 200
# frames estimates a 5% share within about +-1.5%).
AIM_SHARE = 0.05
AIM_OVER = 1.05
AIM_STEP = 0.05
AIM_RANGE = (0.5, 1.25)
MEASURE_SAMPLES = 8


def percentile(values, q: float) -> float:
    """``np.percentile(values, q)`` (linear interpolation) of a short non-empty sequence, without
    numpy's per-call overhead (the selection takes two a frame, of at most MARGIN_FRAMES values)."""
    ordered = sorted(float(value) for value in values)
    rank = (len(ordered) - 1) * float(q) / 100.0
    low = int(rank)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (rank - low)


def median(values) -> float:
    """``np.median`` of a non-empty float array (NaN if any is NaN), by one partition: np.median's
    own checks cost 10-20 µs a call, and the cost fit takes five a traced frame per effect."""
    values = np.asarray(values, np.float64).ravel()
    n = len(values)
    middle = n // 2
    if n % 2:
        value = float(np.partition(values, middle)[middle])
    else:
        low, high = np.partition(values, (middle - 1, middle))[middle - 1:middle + 1].tolist()
        value = (low + high) / 2.0  # np.median's mean of the two
    return value if not np.isnan(values).any() else float("nan")


class FrameTime:
    """The frame-to-frame state of the time the selection may fill."""

    def __init__(self):
        self.errors: deque = deque(maxlen=MARGIN_FRAMES)  # (frame count, measured - predicted ms)
        self.recent_available = deque(maxlen=STEADY_FRAMES)  # the time left (less overhead) of recent frames
        self.log_aim = 0.0  # log of the share of the budget the frame is planned to (see the aim)

    def margin_ms(self, available_ms: float, frames: int) -> float:
        """What the time left loses to the predictions' recent errors, at frame count ``frames``."""
        recent = [error for frame, error in self.errors if frame > frames - MARGIN_FRAMES]
        if not recent:  # nothing measured lately: the cost model's own priors (margined) stand
            return 0.0
        # Few samples: their median (an 80th percentile of two is their maximum, one outlier
        # would hold the time left for MARGIN_FRAMES frames); never more than half the time left.
        quantile = MARGIN_QUANTILE if len(recent) >= MARGIN_MIN_SAMPLES else 50
        return float(np.clip(percentile(recent, quantile), -0.5 * available_ms, 0.5 * available_ms))

    def steady_ms(self, available_ms: float) -> float:
        """This frame's time left (less overhead) recorded; the recent frames' steady one."""
        self.recent_available.append(float(available_ms))
        return percentile(self.recent_available, STEADY_QUANTILE)

    @property
    def aim(self) -> float:
        return float(np.exp(self.log_aim))

    def aimed_time_left(self, time_left_ms: float, budget_ms: float) -> float:
        """The time left for the knapsack when the frame is planned to ``aim`` x the budget."""
        budget = float(np.nan_to_num(budget_ms, nan=0.0, posinf=0.0, neginf=0.0))
        return max(float(time_left_ms) + (self.aim - 1.0) * max(budget, 0.0), 0.0)

    def observe_frame(self, total_ms: float, budget_ms: float, traced: bool = True) -> None:
        """A steady frame's measured time against its budget: the aim's update.  A frame that
        traced nothing and still ended over (the raster half alone) says nothing of the aim:
        not counted, so a budget the raster half overruns does not shut tracing on the frames it
        leaves room in."""
        if not (np.isfinite(total_ms) and np.isfinite(budget_ms) and budget_ms > 0 and total_ms >= 0):
            return
        over = float(total_ms > AIM_OVER * budget_ms)
        if over and not traced:
            return
        self.log_aim = float(np.clip(self.log_aim + AIM_STEP * (AIM_SHARE - over),
                                     np.log(AIM_RANGE[0]), np.log(AIM_RANGE[1])))

    def observe_time(self, predicted_ms: float, measured_ms: float, frames: int) -> None:
        """A traced frame's predicted and measured trace time (the margin's sample), at frame count
        ``frames``."""
        if np.isfinite(predicted_ms) and np.isfinite(measured_ms) and measured_ms >= 0:
            self.errors.append((int(frames), float(measured_ms) - float(predicted_ms)))


class MeasureCost:
    """What measuring the traced change adds to a traced frame (see the module's docstring)."""

    def __init__(self):
        self.measured: deque = deque(maxlen=MEASURE_SAMPLES)  # composite + measurement ms, measured frames
        self.plain: deque = deque(maxlen=MEASURE_SAMPLES)  # composite ms of traced frames that did not

    def observe(self, measured: bool, ms: float) -> None:
        if np.isfinite(ms) and ms >= 0:
            (self.measured if measured else self.plain).append(float(ms))

    def cost_ms(self):
        """The measurement's ms, or None before two frames of each kind were seen."""
        if len(self.measured) < 2 or len(self.plain) < 2:
            return None
        return max(percentile(self.measured, 50) - percentile(self.plain, 50), 0.0)
