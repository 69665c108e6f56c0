"""Steady frame times: the one rule every compared time follows.

A run's first frame pays one-time work (shader compiles, the driver's first
draw, shadow maps, Embree builds) that later frames do not: ~1 s against
~50-300 ms.  Every time that is compared between runs or modes (the means
and p95 of ``summary.json`` and ``sweep.csv``, Table II, the curves' time
axis, the budget between modes) is therefore *steady*: over the frames after
the first (by frame number), each without the one-time work it still
recorded (``setup_ms``, 0 after the first frame of a static replay).  A run
of a single frame has only that frame (its ``setup_ms`` taken out).  The
first frame's own cost is reported on its own (``first_frame_ms``).

Plain Python + numpy, no ``bpy``.
"""
from __future__ import annotations

import math

import numpy as np


def _finite(value) -> float | None:
    if value is None:
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def steady_rows(frame_rows) -> list:
    """The rows of the frames after the first (by frame number); the only row of a one-frame run."""
    rows = sorted(frame_rows, key=lambda row: int(row["frame"]))
    return rows[1:] if len(rows) > 1 else rows


def steady_values(frame_rows, column: str = "total_ms") -> np.ndarray:
    """The steady frames' finite ``column`` values; for ``total_ms`` each less its ``setup_ms``."""
    values = []
    for row in steady_rows(frame_rows):
        value = _finite(row.get(column))
        if value is None:
            continue
        if column == "total_ms":
            value = max(value - (_finite(row.get("setup_ms")) or 0.0), 0.0)
        values.append(value)
    return np.array(values, dtype=np.float64)


def steady_stats(frame_rows, column: str = "total_ms") -> dict:
    """``mean``, ``p50``, ``p95``, ``max`` of :func:`steady_values` (None without values)."""
    values = steady_values(frame_rows, column)
    if not values.size:
        return {"mean": None, "p50": None, "p95": None, "max": None}
    return {"mean": float(values.mean()), "p50": float(np.percentile(values, 50)),
            "p95": float(np.percentile(values, 95)), "max": float(values.max())}


def first_frame_ms(frame_rows, column: str = "total_ms") -> float | None:
    """The first frame's ``column`` as recorded (one-time work included); None without frames."""
    rows = sorted(frame_rows, key=lambda row: int(row["frame"]))
    return _finite(rows[0].get(column)) if rows else None


def over_budget(p95_ms, budget_ms) -> float | None:
    """p95 / budget (None without a positive budget)."""
    p95, budget = _finite(p95_ms), _finite(budget_ms)
    return None if p95 is None or not budget or budget <= 0 else p95 / budget


def speed_against(frame_rows, reference_rows, column: str = "gbuffer_ms") -> float | None:
    """How much slower the machine ran during a run than during ``reference_rows`` (the raster
    run a sweep's budgets were set from): the median, over the steady frames both runs have, of
    ``column`` here / there.  The G-buffer is the same work in every mode and selection, so 1.3
    says every ms the raster half took when the budget was set took 1.3 ms in this run: the time
    left for tracing shrank by that, for every variant alike (this kind of machine drifts by
    tens of percent within minutes).  None without a common frame with both values positive."""
    reference = {}
    for row in steady_rows(reference_rows):
        value = _finite(row.get(column))
        if value is not None and value > 0:
            reference[int(row["frame"])] = value
    ratios = []
    for row in steady_rows(frame_rows):
        value, there = _finite(row.get(column)), reference.get(int(row["frame"]))
        if value is not None and value > 0 and there is not None:
            ratios.append(value / there)
    return float(np.median(ratios)) if ratios else None
