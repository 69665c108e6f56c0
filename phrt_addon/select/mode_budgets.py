"""Budgets that mean the same on any machine: ``--budget-at F``.

A budget in milliseconds only means something on the machine it was chosen on
(a budget below this machine's raster time traces nothing).  ``budget_at = F``
puts the frame budget F of the way from this machine's raster frame time
(F = 0) to its ray traced frame time (F = 1):

    budget_ms = raster_ms + F * (raytrace_ms - raster_ms)

Both frame times are *steady* means: the mean of ``total_ms - setup_ms`` over a
run's frames, i.e. without one-time work (shader compiles, shadow maps drawn
anew, Embree builds) that the budget loop does not count either.  They come

- from existing runs of the same scene, path and resolution on the same CPU
  (:func:`find_reference_runs`: a sweep's own raster and raytrace runs, or
  earlier ``phrt render`` runs beside the new one), or else
- from a short calibration (``engine/runs/calibration.py``: a few frames of each mode).

:class:`BudgetResolution` says which, and goes into ``summary.json`` as
``budget_source`` beside the resolved ``budget_ms``.  Plain Python, no ``bpy``.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import schema
from ..runs import run_files


def budget_between(fraction: float, raster_ms: float, raytrace_ms: float) -> float:
    """The budget ``fraction`` of the way from ``raster_ms`` to ``raytrace_ms`` (never negative)."""
    fraction = float(fraction)
    if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
        raise ValueError(f"budget fraction must be within 0..1, not {fraction!r}")
    raster_ms, raytrace_ms = float(raster_ms), float(raytrace_ms)
    if not (math.isfinite(raster_ms) and math.isfinite(raytrace_ms)):
        raise ValueError(f"frame times must be finite, not {raster_ms!r} and {raytrace_ms!r}")
    return max(raster_ms + fraction * (raytrace_ms - raster_ms), 0.0)


def steady_mean_ms(frame_rows) -> float | None:
    """Mean of ``total_ms - setup_ms`` over frame rows (``frames.csv``); None without frames."""
    values = []
    for row in frame_rows:
        total = row.get("total_ms")
        if total is None or not math.isfinite(float(total)):
            continue
        setup = row.get("setup_ms")
        setup = float(setup) if setup is not None and math.isfinite(float(setup)) else 0.0
        values.append(max(float(total) - setup, 0.0))
    return float(np.mean(values)) if values else None


@dataclass
class BudgetResolution:
    """A ``budget_at`` turned into milliseconds, and where the two frame times came from."""

    fraction: float
    raster_ms: float
    raytrace_ms: float
    method: str  # 'runs' or 'calibration'
    detail: dict = field(default_factory=dict)

    @property
    def budget_ms(self) -> float:
        return budget_between(self.fraction, self.raster_ms, self.raytrace_ms)

    def as_summary(self) -> dict:
        """The ``budget_source`` entry of ``summary.json``."""
        return {"budget_at": self.fraction, "budget_ms": self.budget_ms, "method": self.method,
                "raster_ms": self.raster_ms, "raytrace_ms": self.raytrace_ms, **self.detail}


def _complete_summary(run_dir: Path):
    path = run_dir / schema.SUMMARY_JSON
    if not path.is_file():
        return None
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if summary.get("partial") or summary.get("cancelled") or not summary.get("frame_count"):
        return None
    return summary


def find_reference_runs(search_dirs, scene: str, path: str, resolution, cpu_model: str | None = None):
    """``(raster run dir, raytrace run dir)`` of complete runs of ``scene``/``path`` at ``resolution``
    (on ``cpu_model`` when given) among ``search_dirs`` (run folders, or folders holding run
    folders), the runs with the most frames first; None when either mode is missing."""
    found = {"RASTER": [], "RAYTRACE": []}
    seen = set()
    for folder in search_dirs:
        folder = Path(folder)
        if not folder.is_dir():
            continue
        for candidate in [folder, *sorted(p for p in folder.iterdir() if p.is_dir())]:
            key = candidate.resolve()
            if key in seen:
                continue
            seen.add(key)
            summary = _complete_summary(candidate)
            if summary is None:
                continue
            mode = str(summary.get("mode") or "").upper()
            if mode not in found or summary.get("scene") != scene or summary.get("path") != path:
                continue
            if list(summary.get("resolution") or []) != list(resolution):
                continue
            if cpu_model is not None and (summary.get("machine") or {}).get("cpu_model") != cpu_model:
                continue
            found[mode].append((-int(summary.get("frame_count") or 0), str(candidate), candidate))
    if not found["RASTER"] or not found["RAYTRACE"]:
        return None
    return min(found["RASTER"])[2], min(found["RAYTRACE"])[2]


def from_runs(fraction: float, raster_dir, raytrace_dir) -> BudgetResolution:
    """Resolve ``fraction`` from the steady means of two complete runs."""
    raster_ms = steady_mean_ms(run_files.read_frames(raster_dir))
    raytrace_ms = steady_mean_ms(run_files.read_frames(raytrace_dir))
    if raster_ms is None or raytrace_ms is None:
        raise ValueError(f"runs {raster_dir} and {raytrace_dir} need frames to resolve a budget")
    return BudgetResolution(fraction=float(fraction), raster_ms=raster_ms, raytrace_ms=raytrace_ms, method="runs",
                            detail={"raster_run": str(raster_dir), "raytrace_run": str(raytrace_dir)})


def calibration_frames(frame_range, count: int) -> list[int]:
    """``count`` frames spread evenly over ``frame_range`` (fewer if the range is shorter)."""
    start, end = int(frame_range[0]), int(frame_range[1])
    return sorted({int(round(value)) for value in np.linspace(start, end, max(int(count), 1))})
