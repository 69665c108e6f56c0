"""Runs as the report reads them: loading, grouping by (scene, path), references, the error of each frame
(``errors.csv``) and the Pareto front.  Part of ``phrt_addon/report`` (its ``__init__`` says what the report holds).
"""
import csv
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import defaults
from . import metrics
from ..runs import run_log
from .. import schema
from ..runs import atomic, run_files
from ..runs import steady


ERROR_COLUMNS = ("scene", "path", "run", "mode", "reference", "frame", "flip", "relmse", "psnr_db")


WORST_ELEMENTS = 3


# Frames measured at once (LDR-FLIP and EXR reading release the GIL).
METRIC_THREADS = max(2, min(4, os.cpu_count() or 1))


# sweep.csv: the contract's columns first, then what tells the curves apart.
SWEEP_COLUMNS = ("run", "mode", "cost_mode", "budget_ms", "mean_ms", "p95_ms", "flip", "relmse", "psnr", "regret",
                 "flips_per_100", "popping", "item_popping", "scene", "path", "variant", "budget_at", "selection_weight",
                 "selection_order", "relevance", "frames", "mean_selected", "regret_frames", "regret_share",
                 "captured", "captured_lo", "captured_hi", "judged_frames", "min_regret", "beat_oracle",
                 "p95_over_budget", "within_budget", "first_frame_ms", "variant_name", "speed_vs_raster",
                 "time_left_share", "lockstep_runs", "oracle_reduction")


# The paper's Table II (ms per frame: raster, hybrid, ray tracing) and which of its
# environments each sample scene stands for.
PAPER_TABLE_II = {
    ("sponza", "path1"): (15.2, 102.2, 361.7), ("sponza", "path2"): (22.1, 117.3, 398.5),
    ("sponza", "path3"): (25.2, 139.7, 594.1), ("atrium", "path1"): (26.7, 165.4, 340.4),
    ("atrium", "path2"): (21.8, 125.6, 543.2), ("atrium", "path3"): (30.6, 207.9, 845.3),
}


PAPER_SCENES = {"arcade": "sponza", "atrium": "atrium"}


# Settings of the paper's heuristic as the baseline curve (the other variants change one knob).
BASELINE_VARIANT = ("measured", defaults.SELECTION_WEIGHT, "relevance", "paper", "paper")


@dataclass
class Run:
    """One RUN_DIR as read back for the report."""

    run_dir: Path
    label: str
    summary: dict
    frames: list
    selection: run_files.SelectionStates  # streamed from selection.csv once, kept compact
    images: dict = field(default_factory=dict)  # {frame: path}: only the images the summary commits

    @property
    def scene(self):
        return str(self.summary.get("scene"))

    @property
    def path(self):
        return str(self.summary.get("path"))

    @property
    def group(self):
        return (self.scene, self.path)

    @property
    def mode(self):
        return str(self.summary.get("mode") or "").upper()

    @property
    def variant(self):
        """(cost mode, selection weight I, greedy order, relevance, selection) of the run's
        selection; the selection ``paper``, ``benefit`` or ``benefit+tiers``."""
        summary = self.summary
        weight = summary.get("selection_weight")
        selection = str(summary.get("selection") or "paper").lower()
        if selection == "benefit" and summary.get("quality_tiers"):
            selection = "benefit+tiers"
        return (str(summary.get("cost_mode") or "measured").lower(),
                float(defaults.SELECTION_WEIGHT if weight is None else weight),
                str(summary.get("selection_order") or "relevance").lower(),
                str(summary.get("relevance") or "paper").lower(), selection)

    @property
    def budget_at(self):
        return self.summary.get("budget_at")

    def column(self, name):
        """Frame numbers and the finite values of a frames.csv column."""
        pairs = [(row["frame"], row.get(name)) for row in self.frames
                 if row.get(name) is not None and np.isfinite(row.get(name))]
        frames = np.array([frame for frame, _ in pairs], dtype=int)
        return frames, np.array([value for _, value in pairs], dtype=float)

    def mean(self, name):
        values = self.column(name)[1]
        return float(values.mean()) if values.size else None

    def steady(self, statistic="mean"):
        """A steady statistic of the frame time (``runs/steady.py``: frames after the first, one-time
        work out): ``mean``, ``p50``, ``p95`` or ``max``."""
        return steady.steady_stats(self.frames)[statistic]

    @property
    def first_frame_ms(self):
        return steady.first_frame_ms(self.frames)

    def within_budget(self):
        """Share of the steady frames whose time met the budget (None without a budget)."""
        budget = self.summary.get("budget_ms")
        values = steady.steady_values(self.frames)
        return float((values <= budget).mean()) if budget and values.size else None

    @property
    def variant_name(self):
        """The sweep's name of the run's variant (``measured``, ``error``...: its folder's last part)."""
        return self.run_dir.name.rsplit("-", 1)[-1] if self.mode == "HYBRID" and self.budget_at is not None else None

    def percentile(self, name, q):
        values = self.column(name)[1]
        return float(np.percentile(values, q)) if values.size else None

    def image(self, frame):
        return self.images.get(frame)

    @property
    def has_images(self):
        return bool(self.images)


@dataclass
class RunErrors:
    """A run's error against its group's reference, per frame and averaged."""

    run: Run
    reference: Run = None
    per_frame: list = field(default_factory=list)
    note: str = ""
    # True for the reference itself when it has images: error 0 by definition.
    is_reference: bool = False

    def mean(self, key):
        if self.is_reference:
            return {"flip": 0.0, "relmse": 0.0, "psnr_db": metrics.PSNR_CAP_DB}[key]
        values = np.array([row[key] for row in self.per_frame], dtype=float)
        if not values.size:
            return None
        if key == "psnr_db":
            return metrics.psnr_from_mse(float(np.mean(10.0 ** (-values / 10.0))))
        return float(values.mean())


@dataclass
class ReportFiles:
    """Paths of everything :func:`build_report` wrote."""

    markdown: Path
    html: Path
    errors_csv: Path
    error_vs_time_png: Path
    timeline_png: Path
    sweep_csv: Path = None
    sweep_json: Path = None
    selection_quality_png: Path = None
    # The matplotlib Figures behind the PNGs, by file name (tests read their axes and labels).
    figures: dict = field(default_factory=dict)


def load_run(run_dir):
    """Read a RUN_DIR; ``ValueError`` with the reason if it is not a finished run."""
    run_dir = Path(run_dir)
    if not run_dir.is_dir():
        raise ValueError(f"{run_dir} is not a directory: give a RUN_DIR written by 'phrt render'")
    if not (run_dir / schema.FRAMES_CSV).exists() and not (run_dir / schema.SUMMARY_JSON).exists():
        raise ValueError(f"{run_dir} has no {schema.FRAMES_CSV}: give a RUN_DIR written by 'phrt render'")
    try:
        summary = run_files.read_summary(run_dir)
    except FileNotFoundError:
        raise ValueError(f"{run_dir} has no {schema.SUMMARY_JSON}: it holds no run; render it again") from None
    except ValueError:
        raise ValueError(f"{run_dir}/{schema.SUMMARY_JSON} cannot be read: render the run again") from None
    return Run(run_dir=run_dir, label=run_dir.name, summary=summary, frames=run_files.read_frames(run_dir, summary),
               selection=run_files.SelectionStates(run_dir, summary), images=run_files.run_images(run_dir, summary))


def pareto_front(times_ms, errors):
    """Indices of the points no other point beats on both time and error, by time.

    A point is dominated when another has time <= and error <= with at least
    one strictly smaller; equal points do not dominate each other.
    """
    times = np.asarray(times_ms, dtype=float)[:, None]
    errors = np.asarray(errors, dtype=float)[:, None]
    no_worse = (times.T <= times) & (errors.T <= errors)
    better = (times.T < times) | (errors.T < errors)
    dominated = (no_worse & better).any(axis=1)
    front = np.flatnonzero(~dominated)
    return [int(i) for i in front[np.lexsort((errors[front, 0], times[front, 0]))]]


def unique_labels(runs):
    names = [run.run_dir.name for run in runs]
    for run, name in zip(runs, names):
        if names.count(name) > 1:
            run.label = f"{run.run_dir.parent.name}/{name}"


def find_references(groups, reference):
    """{group: reference Run or None}."""
    chosen = {}
    if reference is not None:
        chosen[reference.group] = reference
    for group, members in groups.items():
        if group not in chosen:
            raytrace = [run for run in members if run.mode == "RAYTRACE"]
            chosen[group] = raytrace[0] if raytrace else None
    if not any(chosen.values()):
        raise ValueError("no reference run: none of the runs is a raytrace run; render one "
                         "with '--mode raytrace' or pass '--reference RUN_DIR'")
    return chosen


def measure_group(members, reference):
    """RunErrors of each run of one (scene, path) group."""
    results = {id(run): RunErrors(run=run, reference=reference) for run in members}
    if reference is None:
        for run in members:
            results[id(run)].note = "no reference run for this path: error not measured"
        return results
    if not reference.has_images:
        for run in members:
            results[id(run)].note = (f"the reference {reference.label} has no frame images "
                                     f"(rendered with --images none): error not measured")
        return results
    compared = []
    for run in members:
        if run is reference:
            results[id(run)].note = "reference"
            results[id(run)].is_reference = True
        elif not run.has_images:
            results[id(run)].note = "no frame images (rendered with --images none): timing only"
        else:
            compared.append(run)
    reference_frames = {row["frame"] for row in reference.frames}
    frames = sorted({row["frame"] for run in compared for row in run.frames} & reference_frames)

    def measure(frame):
        """{id(run): errors or the ValueError} of one frame (FLIP releases the GIL: frames run in parallel)."""
        reference_path = reference.image(frame)
        pending = [run for run in compared if run.image(frame) is not None]
        if reference_path is None or not pending:
            return {}
        reference_image = metrics.read_image(reference_path)  # unreadable: ValueError for the user
        measured = {}
        for run in pending:
            try:
                measured[id(run)] = metrics.image_errors(reference_image, metrics.read_image(run.image(frame)))
            except ValueError as error:
                measured[id(run)] = error
        return measured

    with ThreadPoolExecutor(METRIC_THREADS) as pool:
        for frame, measured in zip(frames, pool.map(measure, frames)):
            for run in compared:
                outcome = results[id(run)]
                if id(run) not in measured or outcome.note:
                    continue
                if isinstance(measured[id(run)], ValueError):
                    outcome.note = f"not compared: {measured[id(run)]}"
                    outcome.per_frame.clear()
                    continue
                outcome.per_frame.append({"frame": frame, **measured[id(run)]})
    for run in compared:
        outcome = results[id(run)]
        if not outcome.note:
            frame_count = len({row["frame"] for row in run.frames})
            if not outcome.per_frame:
                outcome.note = "no frame in common with the reference"
            elif len(outcome.per_frame) < frame_count:
                outcome.note = f"{len(outcome.per_frame)} of {frame_count} frames compared"
    return results


def write_errors_csv(path, runs, errors):
    with atomic.atomic_open(path, "w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(ERROR_COLUMNS)
        for run in runs:
            outcome = errors[id(run)]
            for row in outcome.per_frame:
                values = {"scene": run.scene, "path": run.path, "run": run.label, "mode": run.mode,
                          "reference": outcome.reference.label, **row}
                writer.writerow([run_log.format_value(values[key]) for key in ERROR_COLUMNS])
