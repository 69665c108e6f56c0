"""The computed part of a run's ``summary.json``: statistics of its frames, the selection flips
per element, the machine.  Written by ``run_log.RunLog``; ``flips_per_element_per_100`` is the one
rule for flips (the report's ``run_files.SelectionStates`` computes the same).  Plain Python +
numpy, no ``bpy``.
"""
import math
import os
import platform

import numpy as np

from ..schema import STAGE_COLUMNS
from . import steady


def summarize(frame_rows, selection_rows):
    """The computed part of ``summary.json`` from frame rows and selection rows."""
    def column(name):
        values = [row.get(name) for row in frame_rows]
        return np.array([float(v) for v in values if v is not None and math.isfinite(float(v))])

    def mean(values):
        return float(values.mean()) if values.size else None

    total = column("total_ms")
    frames = [int(row["frame"]) for row in frame_rows]
    budgets = column("budget_ms")
    steady_total = steady.steady_stats(frame_rows)
    flips = flips_per_element_per_100(selection_rows)
    rates = np.array(list(flips.values()), dtype=float)
    return {
        "frame_count": len(frame_rows),
        "frame_start": min(frames) if frames else None,
        "frame_end": max(frames) if frames else None,
        "total_ms": steady_total,
        "all_frames_total_ms": {
            "mean": mean(total),
            "p50": float(np.percentile(total, 50)) if total.size else None,
            "p95": float(np.percentile(total, 95)) if total.size else None,
            "max": float(total.max()) if total.size else None,
        },
        "first_frame_ms": steady.first_frame_ms(frame_rows),
        "p95_over_budget": steady.over_budget(steady_total["p95"], budgets[0] if budgets.size else None),
        "stage_mean_ms": {name: mean(column(name)) for name in STAGE_COLUMNS},
        "predicted_trace_mean_ms": mean(column("predicted_trace_ms")),
        "mean_n_visible": mean(column("n_visible")),
        "mean_n_selected": mean(column("n_selected")),
        "mean_rays": mean(column("rays")),
        "selection_flips_per_element_per_100_frames": {
            "mean": float(rates.mean()) if rates.size else 0.0,
            "max": float(rates.max()) if rates.size else 0.0,
            "per_element": flips,
        },
    }


def _element_states(selection_rows):
    """{element: (frames, selected, visible)} arrays sorted by frame, from the rows with a
    ``selected`` value (a row without ``visible`` counts as visible)."""
    by_element = {}
    for row in selection_rows:
        if row.get("selected") is not None:
            by_element.setdefault(str(row["element"]), []).append(
                (int(row["frame"]), bool(row["selected"]), bool(row.get("visible", True))))
    out = {}
    for element, states in by_element.items():
        states.sort()
        frames, selected, visible = zip(*states)
        out[element] = (np.array(frames, np.int64), np.array(selected, bool), np.array(visible, bool))
    return out


def flips_per_element_per_100(selection_rows):
    """Selection flips of each element per 100 frames of the run.

    A flip is a change of an element's ``selected`` state between two
    consecutive frames (by frame number) in which the element has a row.  The
    count is normalised by the run's length: the number of distinct frames in
    ``selection_rows``.  Returns ``{element: flips * 100 / frames}``.
    """
    states = _element_states(selection_rows)
    frame_count = len({int(frame) for frames, _, _ in states.values() for frame in frames})
    if frame_count == 0:
        return {}
    return {element: 100.0 * int(np.count_nonzero(selected[1:] != selected[:-1])) / frame_count
            for element, (_, selected, _) in states.items()}


def max_flips_in_window(selection_rows, window: int = 10) -> int:
    """The most flips any element made within ``window`` consecutive frames (issue 20: "no
    element flips more than twice in 10 frames").  A flip is a change of ``selected`` between two
    consecutive rows of the element (by frame number) in both of which it is visible (a row's
    ``visible``; rows without it count as visible): an element leaving or entering the view is
    no switch between raster and ray tracing that anyone sees.  A flip belongs to the later
    frame; a window holds the flips between ``window`` frames in a row (``window - 1`` of them)."""
    most = 0
    for frames, selected, visible in _element_states(selection_rows).values():
        flip_frames = frames[1:][(selected[1:] != selected[:-1]) & visible[1:] & visible[:-1]]
        if flip_frames.size:
            # The flips into frames f .. f + window - 2: between the window frames f - 1 .. f + window - 2.
            ends = np.searchsorted(flip_frames, flip_frames + (window - 1), side="left")
            most = max(most, int(np.max(ends - np.arange(flip_frames.size))))
    return most


def machine_info():
    """CPU model and core counts of this machine."""
    model = None
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as cpuinfo:
            for line in cpuinfo:
                if line.lower().startswith(("model name", "hardware")):
                    model = line.split(":", 1)[1].strip() or None
                    break
    except OSError:
        pass
    info = {
        "cpu_model": model or platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
    }
    if hasattr(os, "sched_getaffinity"):
        info["usable_cores"] = len(os.sched_getaffinity(0))
    return info
