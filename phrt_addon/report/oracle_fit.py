"""The oracle's subset held to its time (``engine/runs/oracle.py`` renders; plain Python).

The oracle's knapsack (``oracle.FrameCandidates.choose``) adds up costs measured with each
candidate traced alone.  Traced together they may take longer than that sum (a reflection that
now sees another traced element, shadow rays of several casters over the same receivers): in
eval-18 the chosen subset's own trace took more than the budget's time for tracing plus a tenth
of the budget on 4-8 of 37-110 sampled frames per path on atrium and the showcase, by up to
27 ms.  Such a subset is not "the best subset within the same time", and the share of its
error reduction a run captures is understated.

The oracle renders after the runs, and this machine's speed drifts by tens of percent within
minutes: re-run on eval-18's runs an hour later, every candidate cost 9-21% more (median), and the
oracle's reduction of the raster frame's error at half of the way on atrium/path2 fell from 35% to
15%.  Its timings are put on the runs' clock (:class:`Clock`: the G-buffer pass of its raster
frame of each sampled frame against the runs' raster run's on it), the capacity being theirs.

The chosen subset is rendered and timed (the median of ``oracle.TIMINGS`` timings, as for a
candidate alone); if its trace is over the capacity by more than ``OVER_ALLOWANCE`` x the
budget (the allowance a run's p95 frame has: issue 20's 1.10x), what it took beyond its
predicted cost is charged against the capacity and the knapsack chooses again, up to
``REFITS`` times.  If none of the choices fits, the oracle is the subset measured so far (each
candidate alone, all of them together, the choices) with the lowest LDR-FLIP among those whose
trace fits the capacity itself; the raster frame (nothing traced) always does.
"""
from __future__ import annotations

import numpy as np

OVER_ALLOWANCE = 0.10
REFITS = 3
# The clock ratio is clamped to this range: beyond it the oracle's machine is not the runs' kind.
CLOCK_RANGE = (0.5, 2.0)
CLOCK_WINDOW = 8  # sampled frames whose ratios make the one used (this one's included)


def _positive(values) -> list:
    """The finite positive numbers among ``values`` (None left out)."""
    numbers = [float(value) for value in values if value is not None]
    return [number for number in numbers if np.isfinite(number) and number > 0]


class Clock:
    """How much slower the oracle's machine runs than the runs' did, sampled frame by sampled
    frame: the median of its G-buffer pass timings of the frame (the same draw whatever the mode)
    over the runs' raster run's G-buffer pass on it.  The ratio a frame's timings are divided by is
    the median of the last ``CLOCK_WINDOW`` frames' (it follows the machine's drift through the
    oracle's own minutes), within CLOCK_RANGE; 1 before any frame had both numbers.  The G-buffer
    pass runs on llvmpipe's threads and the trace on Embree's and numpy's, on the same CPU cores:
    a proxy of the machine's speed, not an exact one."""

    def __init__(self):
        self.ratios: list[float] = []  # per sampled frame with both numbers
        self.used: list[float] = []  # the ratio each sampled frame's timings were divided by

    def observe(self, own_timings, runs_ms) -> float:
        own, runs = _positive(own_timings), _positive([runs_ms])
        if own and runs:
            self.ratios.append(float(np.median(own)) / runs[0])
        recent = self.ratios[-CLOCK_WINDOW:]
        ratio = float(np.clip(np.median(recent), *CLOCK_RANGE)) if recent else 1.0
        self.used.append(ratio)
        return ratio

    def summary(self) -> dict:
        """``oracle.json``'s account: the median ratio used, its range, the frames measured."""
        used = self.used or [1.0]
        return {"clock_ratio": float(np.median(used)), "clock_ratio_min": float(min(used)),
                "clock_ratio_max": float(max(used)), "clock_frames": len(self.ratios)}


def within_time(trace_ms: float, capacity_ms: float, budget_ms: float) -> bool:
    """Whether a subset's measured trace fits the budget's time for tracing (with the allowance)."""
    return float(trace_ms) <= float(capacity_ms) + OVER_ALLOWANCE * max(float(budget_ms), 0.0)


def feasible_choice(candidates, capacity_ms: float, budget_ms: float, measure, measured=None) -> tuple:
    """(subset, re-choices made): the knapsack's subset for ``capacity_ms``, chosen again while its
    measured trace is over time (see the module's docstring).  ``measure(subset) -> (trace ms,
    LDR-FLIP)`` renders a subset (called once per subset); ``measured`` {subset: (trace ms,
    LDR-FLIP)} holds subsets already measured (the candidates alone, all of them together, the
    raster frame) and receives the new ones."""
    measured = {} if measured is None else measured
    room = float(capacity_ms)
    subset = candidates.choose(room)
    refits = 0
    while subset:
        if subset not in measured:
            measured[subset] = measure(subset)
        trace_ms = measured[subset][0]
        if within_time(trace_ms, capacity_ms, budget_ms):
            return subset, refits
        if refits == REFITS:
            break
        # What the subset took beyond the sum of its parts, charged to the next choice.
        room -= max(float(trace_ms) - candidates.totals(subset)[0], 0.0)
        subset = candidates.choose(room)
        refits += 1
    if refits == 0:  # nothing fits the capacity: the raster frame
        return frozenset(), 0
    # The choices kept overrunning: the best subset measured whose trace fits the capacity itself.
    fitting = [(flip, sorted(chosen), chosen) for chosen, (trace_ms, flip) in measured.items()
               if float(trace_ms) <= float(capacity_ms)]
    return (min(fitting)[2] if fitting else frozenset()), refits
