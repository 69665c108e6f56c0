"""The report of several runs of a camera path (``phrt report``, docs/formats.md).

:func:`build_report` reads RUN_DIRs (see :mod:`.runlog`) and writes into
``out_dir``:

- ``report.md`` and ``report.html``: a table in the style of the paper's
  Table II (mean ms per frame of the raster, hybrid and raytrace runs, one row
  per (scene, path)), a table of every run (frame time statistics, stages,
  budget), the error of every run against the reference run (mean LDR-FLIP,
  relMSE, PSNR averaged over frames), selection stability (selection flips per
  element per 100 frames, and the worst elements), and the machine;
- ``errors.csv``: the error of every compared frame;
- ``sweep.csv`` and ``sweep.json``: one row per run (:data:`SWEEP_COLUMNS`: mode,
  selection variant, budget, frame time, error, regret, flips, popping), the
  same numbers as the markdown's "Runs on the error-time curve" table;
- ``error_vs_time.png``: mean LDR-FLIP and relMSE against mean frame time, the
  runs of each selection variant joined as a curve from raster through its
  budgets to ray tracing, the Pareto front drawn and each hybrid point's
  budget marked;
- ``selection_quality.png`` (when there are hybrid runs): the heuristic's
  regret against the oracle and the popping per 100 frames against the budget;
- ``timeline.png``: per frame, the frame time of each run with the budget line,
  and the number of selected elements below;
- ``regret.csv`` and ``candidates.csv``: copies of the oracle's per-frame files.

With a sweep (``phrt sweep``), or whenever the runs' folder holds an oracle
folder computed from them (``phrt_addon/oracle.py``), the report adds the
heuristic's regret against the oracle selection; popping
(``phrt_addon/popping.py``) is measured for every run with EXR images.  Table
II is laid out like the paper's, with our ratios beside the paper's own
(milliseconds on different machines do not compare, ratios may).

Runs are grouped by (scene, path), and a run's error is only measured against
the reference of its own group: the ``reference`` argument for its group, or
else the group's raytrace run.  Frames are matched by frame number; images are
``RUN_DIR/frames/NNNN.exr`` (or ``.png``).  A run without images (rendered
with ``--images none``) gets its timings in the report but no error.

Metrics run here, long after rendering, never inside a timed region.  Plots
are matplotlib Figures saved by the Agg canvas (no pyplot, no global backend
switch).  No ``bpy``.
"""
import csv
import html
import json
import os
import re
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import defaults, metrics, oracle, popping, runlog
from .schema import MODE_TITLES, MODES

ERROR_COLUMNS = ("scene", "path", "run", "mode", "reference", "frame", "flip", "relmse", "psnr_db")
WORST_ELEMENTS = 3
# Frames measured at once (LDR-FLIP and EXR reading release the GIL).
METRIC_THREADS = max(2, min(4, os.cpu_count() or 1))
# sweep.csv: the contract's columns first, then what tells the curves apart.
SWEEP_COLUMNS = ("run", "mode", "cost_mode", "budget_ms", "mean_ms", "p95_ms", "flip", "relmse", "psnr", "regret",
                 "flips_per_100", "popping", "scene", "path", "variant", "budget_at", "selection_weight",
                 "selection_order", "relevance", "frames", "mean_selected", "regret_frames", "regret_share")
# The paper's Table II (ms per frame: raster, hybrid, ray tracing) and which of its
# environments each sample scene stands for.
PAPER_TABLE_II = {
    ("sponza", "path1"): (15.2, 102.2, 361.7), ("sponza", "path2"): (22.1, 117.3, 398.5),
    ("sponza", "path3"): (25.2, 139.7, 594.1), ("atrium", "path1"): (26.7, 165.4, 340.4),
    ("atrium", "path2"): (21.8, 125.6, 543.2), ("atrium", "path3"): (30.6, 207.9, 845.3),
}
PAPER_SCENES = {"arcade": "sponza", "atrium": "atrium"}
# Settings of the paper's heuristic as the baseline curve (the other variants change one knob).
BASELINE_VARIANT = ("measured", defaults.SELECTION_WEIGHT, "relevance", "paper")


@dataclass
class Run:
    """One RUN_DIR as read back for the report."""

    run_dir: Path
    label: str
    summary: dict
    frames: list
    selection: list

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
        """(cost mode, selection weight I, greedy order, relevance) of the run's selection."""
        summary = self.summary
        weight = summary.get("selection_weight")
        return (str(summary.get("cost_mode") or "measured").lower(),
                float(defaults.SELECTION_WEIGHT if weight is None else weight),
                str(summary.get("selection_order") or "relevance").lower(),
                str(summary.get("relevance") or "paper").lower())

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

    def percentile(self, name, q):
        values = self.column(name)[1]
        return float(np.percentile(values, q)) if values.size else None

    def image(self, frame):
        return runlog.frame_image_path(self.run_dir, frame)

    @property
    def has_images(self):
        return any(self.image(row["frame"]) is not None for row in self.frames)


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
    if not (run_dir / runlog.FRAMES_CSV).exists():
        raise ValueError(f"{run_dir} has no {runlog.FRAMES_CSV}: give a RUN_DIR written by 'phrt render'")
    try:
        summary = runlog.read_summary(run_dir)
    except FileNotFoundError:
        raise ValueError(f"{run_dir} has no {runlog.SUMMARY_JSON}: the run did not finish; "
                         f"render it again") from None
    return Run(run_dir=run_dir, label=run_dir.name, summary=summary,
               frames=runlog.read_frames(run_dir), selection=runlog.read_selection(run_dir))


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


def _unique_labels(runs):
    names = [run.run_dir.name for run in runs]
    for run, name in zip(runs, names):
        if names.count(name) > 1:
            run.label = f"{run.run_dir.parent.name}/{name}"


def _references(groups, reference):
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


def _measure_group(members, reference):
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


def build_report(run_dirs, reference=None, out_dir="out/report", oracle_dir=None):
    """Write the report of ``run_dirs`` into ``out_dir``; returns :class:`ReportFiles`.

    ``reference`` is a RUN_DIR (added to the runs if it is not among them);
    by default each path's raytrace run.  ``oracle_dir`` is an oracle folder
    (``phrt_addon/oracle.py``); by default the ``oracle`` folder beside the runs,
    when they share one parent folder.  Raises ``ValueError`` with a message
    for the user when a RUN_DIR is unusable or there is no reference at all.
    """
    paths = []
    for run_dir in list(run_dirs) + ([reference] if reference is not None else []):
        if Path(run_dir).resolve() not in [p.resolve() for p in paths]:
            paths.append(Path(run_dir))
    if not paths:
        raise ValueError("no RUN_DIR given")
    runs = [load_run(path) for path in paths]
    _unique_labels(runs)
    reference_run = None
    if reference is not None:
        reference_run = next(run for run in runs if run.run_dir.resolve() == Path(reference).resolve())
    groups = {}
    for run in runs:
        groups.setdefault(run.group, []).append(run)
    references = _references(groups, reference_run)

    errors = {}
    for group, members in groups.items():
        errors.update(_measure_group(members, references[group]))

    pops = _measure_popping(runs, references)
    oracle_results = _oracle_results(runs, oracle_dir)
    regrets = _regrets(runs, oracle_results)

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = ReportFiles(markdown=out_dir / "report.md", html=out_dir / "report.html",
                        errors_csv=out_dir / "errors.csv",
                        error_vs_time_png=out_dir / "error_vs_time.png",
                        timeline_png=out_dir / "timeline.png",
                        sweep_csv=out_dir / "sweep.csv", sweep_json=out_dir / "sweep.json")
    rows = sweep_rows(runs, errors, regrets, pops, references)
    _write_errors_csv(files.errors_csv, runs, errors)
    _write_sweep(files.sweep_csv, files.sweep_json, rows, oracle_results)
    files.figures[files.error_vs_time_png.name] = _plot_error_vs_time(files.error_vs_time_png, groups, errors)
    files.figures[files.timeline_png.name] = _plot_timeline(files.timeline_png, groups)
    if any(run.mode == "HYBRID" for run in runs):
        files.selection_quality_png = out_dir / "selection_quality.png"
        files.figures[files.selection_quality_png.name] = _plot_selection_quality(
            files.selection_quality_png, groups, regrets, pops)
    if oracle_results is not None:
        oracle.write_csv(out_dir / oracle.REGRET_CSV, oracle.REGRET_COLUMNS,
                         [{**row, **{key: ";".join(row[key]) for key in ("heuristic", "oracle", "oracle_only",
                                                                         "heuristic_only")}}
                          for row in oracle_results.regret_rows])
        oracle.write_csv(out_dir / oracle.CANDIDATES_CSV, ("sweep",) + oracle.CANDIDATE_COLUMNS,
                         oracle_results.candidate_rows)
    sections = _sections(runs, groups, references, errors, files, rows=rows, regrets=regrets, pops=pops,
                         oracle_results=oracle_results)
    files.markdown.write_text(_markdown(sections), encoding="utf-8")
    files.html.write_text(_html(sections), encoding="utf-8")
    return files


def _measure_popping(runs, references):
    """{id(run): PoppingResult} for runs with images whose path has a reference with images."""
    pops = {}
    reference_maps = {}  # shared by the runs (threads may both compute a map: same value)
    measured = []
    for run in runs:
        reference = references.get(run.group)
        if reference is None or not reference.has_images or not run.has_images:
            continue
        if run is reference:
            pops[id(run)] = popping.PoppingResult(frame_count=len(run.frames))  # the reference: 0 by definition
            continue
        measured.append((run, reference))
    with ThreadPoolExecutor(METRIC_THREADS) as pool:
        results = pool.map(lambda pair: popping.measure_popping(pair[0].run_dir, pair[1].run_dir, pair[0].selection,
                                                                reference_maps), measured)
        for (run, _), result in zip(measured, results):
            pops[id(run)] = result
    return pops


def _oracle_results(runs, oracle_dir):
    """The oracle folder's results (several folders, e.g. two sweeps, are merged)."""
    if oracle_dir is None:
        parents = {run.run_dir.resolve().parent for run in runs}
        if len(parents) != 1:
            return None
        oracle_dir = next(iter(parents)) / oracle.ORACLE_DIR
    folders = [oracle_dir] if isinstance(oracle_dir, (str, Path)) else list(oracle_dir)
    found = [results for results in map(oracle.read_results, folders) if results is not None]
    if not found:
        return None
    for results in found:  # which sweep each candidate row came from
        results.candidate_rows = [{"sweep": results.folder.resolve().parent.name, **row}
                                  for row in results.candidate_rows]
    merged = found[0]
    for results in found[1:]:
        merged.info = {**merged.info, "runs": {**merged.info.get("runs", {}), **results.info.get("runs", {})}}
        merged.regret_rows = merged.regret_rows + results.regret_rows
        merged.candidate_rows = merged.candidate_rows + results.candidate_rows
    return merged


@dataclass
class RunRegret:
    """The oracle's verdict on one hybrid run."""

    frames: int = 0
    mean: float | None = None
    max: float | None = None
    heuristic_flip: float | None = None
    oracle_flip: float | None = None
    differs: int = 0
    overran: int = 0
    lost_share: float | None = None  # mean (heuristic - oracle) / (raster - oracle) where the oracle gains
    oracle_only: dict = field(default_factory=dict)
    heuristic_only: dict = field(default_factory=dict)
    note: str = ""


def _regrets(runs, results):
    """{id(run): RunRegret} of the hybrid runs."""
    regrets = {}
    for run in runs:
        if run.mode != "HYBRID":
            continue
        if results is None:
            regrets[id(run)] = RunRegret(note="no oracle (run 'phrt sweep')")
            continue
        name = run.run_dir.name
        if not results.is_current_for(name, run.run_dir):
            note = "not in the oracle" if name not in results.runs() else "oracle is older than the run"
            regrets[id(run)] = RunRegret(note=note)
            continue
        rows = results.rows_of(name)
        if not rows:
            regrets[id(run)] = RunRegret(note="no sampled frame")
            continue
        values = np.array([row["regret"] for row in rows], dtype=float)
        raster = {int(row["frame"]): float(row["flip_raster"]) for row in results.candidate_rows
                  if row.get("sweep", results.folder.resolve().parent.name) == run.run_dir.resolve().parent.name}
        shares = [(row["heuristic_flip"] - row["oracle_flip"]) / (raster[row["frame"]] - row["oracle_flip"])
                  for row in rows if row["frame"] in raster and raster[row["frame"]] - row["oracle_flip"] > 1e-6]
        oracle_only, heuristic_only = {}, {}
        for row in rows:
            for element in row["oracle_only"]:
                oracle_only[element] = oracle_only.get(element, 0) + 1
            for element in row["heuristic_only"]:
                heuristic_only[element] = heuristic_only.get(element, 0) + 1
        regrets[id(run)] = RunRegret(
            frames=len(rows), mean=float(values.mean()), max=float(values.max()),
            heuristic_flip=float(np.mean([row["heuristic_flip"] for row in rows])),
            oracle_flip=float(np.mean([row["oracle_flip"] for row in rows])),
            differs=sum(1 for row in rows if set(row["oracle"]) != set(row["heuristic"])),
            overran=sum(1 for row in rows if row["capacity_ms"] is not None and row["time_left_ms"] is not None
                        and row["capacity_ms"] > row["time_left_ms"]),
            lost_share=float(np.mean(shares)) if shares else None,
            oracle_only=oracle_only, heuristic_only=heuristic_only)
    return regrets


def variant_label(variant) -> str:
    """A short name of a selection variant: the paper's heuristic and what differs from it."""
    cost_mode, weight, order, relevance = variant
    parts = ["error-aware R" if relevance == "error" else "paper R"]
    parts.append(f"{cost_mode} cost")
    parts.append(f"I={weight:g}")
    if order == "relevance_per_ms":
        parts.append("R/ms order")
    return ", ".join(parts)


def sweep_rows(runs, errors, regrets, pops, references):
    """One dict per run with the keys of SWEEP_COLUMNS (None where not applicable)."""
    rows = []
    for run in runs:
        outcome = errors[id(run)]
        regret = regrets.get(id(run))
        pop = pops.get(id(run))
        hybrid = run.mode == "HYBRID"
        rates = np.array(list(runlog.flips_per_element_per_100(run.selection).values()), dtype=float)
        cost_mode, weight, order, relevance = run.variant
        rows.append({
            "run": run.label, "mode": run.mode, "cost_mode": cost_mode if hybrid else None,
            "budget_ms": run.summary.get("budget_ms") if hybrid else None,
            "mean_ms": run.mean("total_ms"), "p95_ms": run.percentile("total_ms", 95),
            "flip": outcome.mean("flip"), "relmse": outcome.mean("relmse"), "psnr": outcome.mean("psnr_db"),
            "regret": regret.mean if regret is not None else None,
            "flips_per_100": float(rates.mean()) if rates.size else 0.0,
            "popping": pop.per_100_frames() if pop is not None else None,
            "scene": run.scene, "path": run.path,
            "variant": variant_label(run.variant) if hybrid else run.mode.lower(),
            "budget_at": run.budget_at if hybrid else None,
            "selection_weight": weight if hybrid else None, "selection_order": order if hybrid else None,
            "relevance": relevance if hybrid else None, "frames": len(run.frames),
            "mean_selected": run.mean("n_selected"),
            "regret_frames": regret.frames if regret is not None else None,
            "regret_share": regret.lost_share if regret is not None else None,
        })
    return rows


def _write_sweep(csv_path, json_path, rows, oracle_results):
    temporary = csv_path.with_name(csv_path.name + ".tmp")
    with open(temporary, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(SWEEP_COLUMNS)
        for row in rows:
            writer.writerow([runlog.format_value(row[key]) for key in SWEEP_COLUMNS])
    os.replace(temporary, csv_path)
    document = {"columns": list(SWEEP_COLUMNS), "runs": [{key: row[key] for key in SWEEP_COLUMNS} for row in rows],
                "oracle": None if oracle_results is None else {
                    "every": oracle_results.info.get("every"), "frames": oracle_results.info.get("frames"),
                    "note": oracle_results.info.get("note")}}
    document = runlog._round_json(runlog._json_safe(document))
    temporary = json_path.with_name(json_path.name + ".tmp")
    temporary.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    os.replace(temporary, json_path)


def _write_errors_csv(path, runs, errors):
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(ERROR_COLUMNS)
        for run in runs:
            outcome = errors[id(run)]
            for row in outcome.per_frame:
                values = {"scene": run.scene, "path": run.path, "run": run.label, "mode": run.mode,
                          "reference": outcome.reference.label, **row}
                writer.writerow([runlog.format_value(values[key]) for key in ERROR_COLUMNS])


def _figure(**kwargs):
    """A matplotlib Figure drawn by the Agg canvas, without pyplot's global state."""
    from matplotlib.figure import Figure

    return Figure(**kwargs)


def _plot_error_vs_time(path, groups, errors):
    """One row per (scene, path) (errors of different paths do not compare): mean LDR-FLIP
    and mean relMSE against mean frame time."""
    figure = _figure(figsize=(16, 7.5 * len(groups)))
    panels = figure.subplots(len(groups), 2, squeeze=False)
    for row, (group, members) in enumerate(groups.items()):
        _plot_curves(panels[row, 0], group, members, errors, "flip",
                     "mean LDR-FLIP against the reference (lower is better)")
        _plot_curves(panels[row, 1], group, members, errors, "relmse",
                     "mean relMSE against the reference (lower is better)")
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    return figure


def _variant_styles(members):
    """{variant: (colour, line width, label)}: the paper's heuristic first and boldest."""
    variants = sorted({run.variant for run in members if run.mode == "HYBRID"},
                      key=lambda v: (v != BASELINE_VARIANT, v[3] != "paper", v))
    colours = ["tab:blue", "tab:red", "tab:green", "tab:orange", "tab:purple", "tab:brown", "tab:pink",
               "tab:olive", "tab:cyan", "tab:gray"]
    return {variant: (colours[index % len(colours)], 2.2 if variant == BASELINE_VARIANT else 1.3,
                      variant_label(variant)) for index, variant in enumerate(variants)}


def _plot_curves(axes, group, members, errors, key, ylabel):
    axes.set_title(f"{group[0]} / {group[1]}: {ylabel.split(' against')[0]} against frame time")
    axes.set_xlabel("mean frame time (ms)")
    axes.set_ylabel(ylabel)
    axes.grid(True, alpha=0.3)
    points = [(run, run.mean("total_ms"), errors[id(run)].mean(key)) for run in members]
    points = [(run, time, error) for run, time, error in points if time is not None and error is not None]
    if not points:
        axes.text(0.5, 0.5, "no error measured for this path\n(see the error table)",
                  ha="center", va="center", transform=axes.transAxes)
        return
    times = np.array([time for _, time, _ in points])
    values = np.array([error for _, _, error in points])
    ends = {mode: next(((time, error) for run, time, error in points if run.mode == mode), None)
            for mode in ("RASTER", "RAYTRACE")}
    styles = _variant_styles([run for run, _, _ in points])
    budgets = {}
    for variant, (colour, width, label) in styles.items():
        curve = sorted(((run.budget_at if run.budget_at is not None else -1.0, time, error, run)
                        for run, time, error in points if run.mode == "HYBRID" and run.variant == variant),
                       key=lambda item: (item[0], item[1]))
        xs = [item[1] for item in curve]
        ys = [item[2] for item in curve]
        line_x = ([ends["RASTER"][0]] if ends["RASTER"] else []) + xs + ([ends["RAYTRACE"][0]] if ends["RAYTRACE"] else [])
        line_y = ([ends["RASTER"][1]] if ends["RASTER"] else []) + ys + ([ends["RAYTRACE"][1]] if ends["RAYTRACE"] else [])
        axes.plot(line_x, line_y, color=colour, linewidth=width, alpha=0.85, zorder=2)
        axes.scatter(xs, ys, color=colour, s=36, zorder=4, label=label)
        for _, time, error, run in curve:
            budget = run.summary.get("budget_ms")
            if budget:
                budgets.setdefault(round(float(budget), 3), run.budget_at)
                # The budget mark: a tick at the budget, joined to the point it belongs to.
                axes.plot([budget, time], [error, error], color=colour, linestyle=":", linewidth=0.9, zorder=1)
                axes.scatter([budget], [error], marker="|", s=160, color=colour, zorder=3)
    for mode, marker, label in (("RASTER", "s", "raster"), ("RAYTRACE", "D", "ray traced (reference)")):
        if ends[mode]:
            axes.scatter([ends[mode][0]], [ends[mode][1]], marker=marker, s=60, color="black", zorder=5,
                         label=label)
    if len(points) <= 5:  # few runs: name them
        for run, time, error in points:
            axes.annotate(run.label, (time, error), fontsize=8, textcoords="offset points", xytext=(6, 6))
    front = pareto_front(times, values)
    axes.plot(times[front], values[front], color="0.35", drawstyle="steps-post", linestyle="--",
              linewidth=1.2, label="Pareto front", zorder=1)
    top = float(values.max()) if values.max() > 0 else 1.0
    for budget, fraction in sorted(budgets.items()):
        axes.axvline(budget, color="tab:red", linestyle=":", linewidth=0.8, alpha=0.6)
        text = f"budget {budget:.0f} ms" + (f" (at {fraction:.2f})" if fraction is not None else "")
        axes.annotate(text, (budget, 1.0), xycoords=("data", "axes fraction"), xytext=(3, -4),
                      textcoords="offset points", fontsize=7, color="tab:red", rotation=90, va="top")
    axes.scatter([], [], marker="|", s=100, color="0.3", label="budget of a hybrid point (dotted to it)")
    axes.set_xlim(0.0, 1.08 * max(float(times.max()), *budgets.keys(), 1.0))
    axes.set_ylim(0.0, 1.18 * top)
    axes.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.11), ncol=3, frameon=False)


def _plot_selection_quality(path, groups, regrets, pops):
    """Per (scene, path): mean regret against the oracle and popping per 100 frames, against the budget."""
    hybrid_groups = {group: [run for run in members if run.mode == "HYBRID"] for group, members in groups.items()}
    hybrid_groups = {group: members for group, members in hybrid_groups.items() if members}
    figure = _figure(figsize=(16, 5.5 * len(hybrid_groups)))
    panels = figure.subplots(len(hybrid_groups), 2, squeeze=False)
    for row, (group, members) in enumerate(hybrid_groups.items()):
        styles = _variant_styles(members)
        for axes, title, ylabel, value_of in (
                (panels[row, 0], "regret against the oracle",
                 "mean regret: LDR-FLIP(heuristic) - LDR-FLIP(oracle)",
                 lambda run: regrets.get(id(run)).mean if regrets.get(id(run)) else None),
                (panels[row, 1], "popping", "popping per 100 frames (summed LDR-FLIP excess)",
                 lambda run: pops[id(run)].per_100_frames() if id(run) in pops else None)):
            axes.set_title(f"{group[0]} / {group[1]}: {title}")
            axes.set_xlabel("frame budget (ms)")
            axes.set_ylabel(ylabel)
            axes.grid(True, alpha=0.3)
            axes.axhline(0.0, color="0.4", linewidth=0.8)
            drawn = False
            for variant, (colour, width, label) in styles.items():
                curve = sorted((run.summary.get("budget_ms"), value_of(run)) for run in members
                               if run.variant == variant and run.summary.get("budget_ms") is not None
                               and value_of(run) is not None)
                if curve:
                    drawn = True
                    axes.plot([x for x, _ in curve], [y for _, y in curve], marker="o", color=colour,
                              linewidth=width, label=label)
            if drawn:
                axes.legend(fontsize=7, loc="best")
            else:
                axes.text(0.5, 0.5, "not measured (see the report's notes)", ha="center", va="center",
                          transform=axes.transAxes)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    return figure


def _plot_timeline(path, groups):
    figure = _figure(figsize=(10, 5.5 * len(groups)))
    axes = figure.subplots(2 * len(groups), 1, squeeze=False,
                           gridspec_kw={"height_ratios": [2, 1] * len(groups)})
    for index, (group, members) in enumerate(groups.items()):
        time_axes, selected_axes = axes[2 * index, 0], axes[2 * index + 1, 0]
        budgeted = [run for run in members if run.mode == "HYBRID"] or members[:1]
        for run in members:
            frames, total = run.column("total_ms")
            line, = time_axes.plot(frames, total, linewidth=1.2,
                                   label=f"{run.label} ({run.mode.lower()})")
            frames, selected = run.column("n_selected")
            selected_axes.step(frames, selected, where="mid", linewidth=1.2,
                               color=line.get_color())
            frames, budget = run.column("budget_ms")
            if run in budgeted and budget.size:
                time_axes.step(frames, budget, where="mid", color=line.get_color(),
                               linestyle="--", linewidth=1.0,
                               label=f"budget of {run.label} ({budget[-1]:g} ms)")
        time_axes.set_title(f"{group[0]} / {group[1]}")
        time_axes.set_ylabel("frame time (ms)")
        time_axes.set_ylim(0.0, 1.1 * max([1.0] + [float(line.get_ydata().max())
                                                  for line in time_axes.get_lines()
                                                  if len(line.get_ydata())]))
        time_axes.grid(True, alpha=0.3)
        time_axes.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
        selected_axes.set_ylabel("selected elements")
        selected_axes.set_xlabel("frame")
        selected_axes.set_ylim(bottom=0.0)
        selected_axes.yaxis.get_major_locator().set_params(integer=True)
        selected_axes.xaxis.get_major_locator().set_params(integer=True)
        time_axes.xaxis.get_major_locator().set_params(integer=True)
        selected_axes.grid(True, alpha=0.3)
        selected_axes.sharex(time_axes)
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    return figure


def _ms(value):
    return "–" if value is None else f"{value:.1f}"


def _number(value, spec):
    return "–" if value is None else format(value, spec)


@dataclass
class _Table:
    title: str
    header: list
    rows: list
    intro: str = ""


def table_ii_hybrid(members):
    """The hybrid run a Table II row shows: the paper's heuristic (baseline variant) at the budget
    nearest the sample scenes' Budget At, else the first hybrid run."""
    hybrids = [run for run in members if run.mode == "HYBRID"]
    if not hybrids:
        return None
    baseline = [run for run in hybrids if run.variant == BASELINE_VARIANT] or hybrids
    return min(baseline, key=lambda run: abs((run.budget_at if run.budget_at is not None
                                              else defaults.BUDGET_AT) - defaults.BUDGET_AT))


def _ratio(numerator, denominator):
    return None if numerator is None or not denominator else numerator / denominator


def table_ii_rows(groups):
    """Rows of the Table II section: scene, path, raster / hybrid / ray tracing ms, our ratios beside
    the paper's, and the hybrid run shown."""
    rows = []
    for (scene, path), members in groups.items():
        means = {}
        for mode in ("RASTER", "RAYTRACE"):
            runs = [run for run in members if run.mode == mode]
            means[mode] = runs[0].mean("total_ms") if runs else None
        hybrid = table_ii_hybrid(members)
        means["HYBRID"] = hybrid.mean("total_ms") if hybrid is not None else None
        paper = PAPER_TABLE_II.get((PAPER_SCENES.get(scene, scene), path))
        rows.append([scene, path, _ms(means["RASTER"]), _ms(means["HYBRID"]), _ms(means["RAYTRACE"]),
                     _number(_ratio(means["HYBRID"], means["RASTER"]), ".2f"),
                     _number(_ratio(paper[1], paper[0]) if paper else None, ".2f"),
                     _number(_ratio(means["RAYTRACE"], means["HYBRID"]), ".2f"),
                     _number(_ratio(paper[2], paper[1]) if paper else None, ".2f"),
                     hybrid.label if hybrid is not None else "–"])
    return rows


def _sections(runs, groups, references, errors, files, rows=None, regrets=None, pops=None, oracle_results=None):
    """The report as a list of items: ('h', text), ('p', text), ('table', _Table), ('img', file)."""
    rows = rows or []
    regrets = regrets or {}
    pops = pops or {}
    items = [("h1", "PHRT report")]
    items.append(("p", f"{len(runs)} runs of {len(groups)} camera path(s). Frame times are "
                       f"means over the frames of each run, in milliseconds."))

    items.append(("table", _Table(
        "Render times (ms per frame), after the paper's Table II",
        ["Scene", "Path", "Raster rendering", "Hybrid rendering", "Ray tracing rendering", "Hybrid / raster",
         "Paper: hybrid / raster", "Ray tracing / hybrid", "Paper: ray tracing / hybrid", "Hybrid run"],
        table_ii_rows(groups),
        "Mean time to render a frame of the path in each mode, laid out like the paper's Table II, "
        "with our ratios beside the paper's own (its Table II: 640x480, 1000 frames per path, a GTX 460M); "
        "milliseconds on different machines do not compare, ratios may. The arcade scene stands for the "
        "paper's Sponza, atrium for its atrium. The hybrid column is the paper's heuristic (measured "
        f"cost, I = {defaults.SELECTION_WEIGHT:g}, R order, paper relevance) at the budget nearest "
        f"{defaults.BUDGET_AT:g} of the way from raster to ray traced time, or the only hybrid run.")))

    run_rows = []
    for run in runs:
        frames, total = run.column("total_ms")
        budget = run.summary.get("budget_ms")
        within = (f"{100.0 * np.mean(total <= budget):.0f}%"
                  if budget and total.size and run.mode == "HYBRID" else "–")
        run_rows.append([
            run.label, f"{run.scene} / {run.path}", run.mode.lower(),
            _number(budget, "g"), str(len(run.frames)), _ms(run.mean("total_ms")),
            _ms(run.percentile("total_ms", 50)), _ms(run.percentile("total_ms", 95)),
            _ms(float(total.max()) if total.size else None),
            _ms(run.mean("raster_ms")), _ms(run.mean("select_ms")), _ms(run.mean("trace_ms")),
            _ms(run.mean("composite_ms")), _number(run.mean("n_selected"), ".1f"), within])
    items.append(("table", _Table(
        "Runs",
        ["Run", "Scene / path", "Mode", "Budget ms", "Frames", "Mean ms", "p50 ms", "p95 ms",
         "Max ms", "Raster ms", "Select ms", "Trace ms", "Composite ms", "Mean selected",
         "Within budget"], run_rows,
        "Stage columns are means per frame; 'within budget' is the share of hybrid frames "
        "whose total time met the budget.")))

    error_rows = []
    for run in runs:
        outcome = errors[id(run)]
        reference = references[run.group]
        error_rows.append([
            run.label, f"{run.scene} / {run.path}", run.mode.lower(),
            reference.label if reference else "–",
            str(len(outcome.per_frame)) if run is not reference else str(len(run.frames)),
            _number(outcome.mean("flip"), ".4f"), _number(outcome.mean("relmse"), ".3g"),
            _number(outcome.mean("psnr_db"), ".2f"), outcome.note])
    items.append(("table", _Table(
        "Error against the reference",
        ["Run", "Scene / path", "Mode", "Reference", "Frames compared", "Mean LDR-FLIP",
         "relMSE", "PSNR dB", "Note"], error_rows,
        f"Frames are matched by frame number; every image is tone-mapped the same way "
        f"(clamp to [0, 1], sRGB encoding: Blender's 'Standard' view transform) before "
        f"LDR-FLIP (67 pixels per degree) and PSNR; relMSE = mean((x - y)^2 / (y^2 + "
        f"{metrics.RELMSE_EPSILON:g})) on linear HDR values. Values are means over the "
        f"compared frames, except PSNR: the PSNR of the mean per-frame MSE (a frame identical "
        f"to the reference would otherwise count at the {metrics.PSNR_CAP_DB:g} dB cap). "
        f"Per-frame values: [{files.errors_csv.name}]({files.errors_csv.name}).")))
    items.append(("img", files.error_vs_time_png.name,
                  "Mean LDR-FLIP (left) and relMSE (right) against mean frame time: each selection variant's "
                  "runs joined from raster through its budgets to ray tracing, the Pareto front dashed, each "
                  "hybrid point's budget marked (a tick dotted to the point, and a red line per budget)."))
    items += _sweep_sections(rows, groups, regrets, pops, oracle_results, files)
    items.append(("img", files.timeline_png.name,
                  "Frame time of each run per frame with the budget (dashed), and selected elements."))

    stability_rows = []
    for run in runs:
        rates = runlog.flips_per_element_per_100(run.selection)
        worst = sorted(((rate, element) for element, rate in rates.items() if rate > 0),
                       key=lambda item: (-item[0], item[1]))[:WORST_ELEMENTS]
        values = np.array(list(rates.values()), dtype=float)
        stability_rows.append([
            run.label, run.mode.lower(), str(len(rates)),
            _number(float(values.mean()) if values.size else None, ".2f"),
            _number(float(values.max()) if values.size else None, ".2f"),
            ", ".join(f"{element} ({rate:.2f})" for rate, element in worst) or "none"])
    items.append(("table", _Table(
        "Selection stability",
        ["Run", "Mode", "Elements", "Mean flips / element / 100 frames", "Max",
         "Worst elements"], stability_rows,
        "A flip is an element switching between raster and ray tracing from one frame to "
        "the next; the paper asks that no element changes repeatedly.")))

    machine_rows = []
    for key, title in (("blender_version", "Blender"), ("embreex_version", "embreex")):
        machine_rows.append([title, ", ".join(sorted({str(run.summary.get(key)) for run in runs}))])
    for key, title in (("cpu_model", "CPU"), ("cores", "Cores")):
        machine_rows.append([title, ", ".join(sorted(
            {str((run.summary.get("machine") or {}).get(key)) for run in runs}))])
    items.append(("table", _Table("Machine and versions", ["", ""], machine_rows)))
    return items


def _signed(value, spec):
    return "–" if value is None else format(value, "+" + spec)


def _top(counts, limit=WORST_ELEMENTS):
    ranked = sorted(counts.items(), key=lambda item: (-item[1], item[0]))[:limit]
    return ", ".join(f"{name} ({count})" for name, count in ranked) or "none"


SWEEP_TABLE_TITLE = "Runs on the error-time curve"
# How the sweep table shows each column of sweep.csv (the test of their agreement reads this).
SWEEP_TABLE_FORMATS = (("run", "Run", None), ("mode", "Mode", None), ("variant", "Selection", None),
                       ("budget_at", "Budget at", ".2f"), ("budget_ms", "Budget ms", ".1f"),
                       ("mean_ms", "Mean ms", ".1f"), ("p95_ms", "p95 ms", ".1f"), ("flip", "LDR-FLIP", ".4f"),
                       ("relmse", "relMSE", ".4g"), ("psnr", "PSNR dB", ".2f"), ("regret", "Regret", ".4f"),
                       ("regret_share", "Regret share", ".2f"),
                       ("flips_per_100", "Flips / element / 100 frames", ".2f"),
                       ("popping", "Popping / 100 frames", ".4f"), ("mean_selected", "Mean selected", ".1f"))


def _sweep_sections(rows, groups, regrets, pops, oracle_results, files):
    items = []
    items.append(("table", _Table(
        SWEEP_TABLE_TITLE, [title for _, title, _ in SWEEP_TABLE_FORMATS],
        [[(_number(row[key], spec) if spec else str(row[key])) if row[key] is not None else "–"
          for key, _, spec in SWEEP_TABLE_FORMATS] for row in rows],
        f"One row per run, the numbers of [{files.sweep_csv.name}]({files.sweep_csv.name}) and "
        f"[{files.sweep_json.name}]({files.sweep_json.name}). Selection: the relevance (the paper's R or the "
        "error-aware one), the cost model, the selection weight I and the greedy order (the paper's R order "
        "unless 'R/ms order'). Budget at: the fraction of the way from raster to ray traced frame time the "
        "budget was resolved from. Regret: mean over the oracle's sampled frames; regret share: the regret as a share "
        "of what the oracle gains over raster (see Regret against the oracle). Popping: summed "
        "popping of all flips per 100 frames (see Popping).")))

    by_budget = {}
    for row in rows:
        if row["mode"] == "HYBRID" and row["budget_at"] is not None:
            by_budget.setdefault((row["scene"], row["path"]), {}).setdefault(row["variant"], {})[
                row["budget_at"]] = row
    for (scene, path), variants in by_budget.items():
        fractions = sorted({fraction for per_budget in variants.values() for fraction in per_budget})
        if len(variants) > 1:
            items.append(("table", _Table(
                f"Selection knobs: {scene} / {path}",
                ["Selection"] + [f"at {fraction:.2f}: LDR-FLIP / regret" for fraction in fractions],
                [[variant] + [(f"{_number(per_budget[f]['flip'], '.4f')} / {_number(per_budget[f]['regret'], '.4f')}"
                               if f in per_budget else "–") for f in fractions]
                 for variant, per_budget in sorted(variants.items(), key=lambda item: (
                     item[0] != variant_label(BASELINE_VARIANT), item[0]))],
                "Which part of the selection loses the error: each row changes one knob of the paper's "
                "heuristic (the cost model, the selection weight I, the greedy order, the relevance); "
                "columns are the budgets of the sweep.")))
        paper_label = variant_label(BASELINE_VARIANT)
        error_label = variant_label(BASELINE_VARIANT[:3] + ("error",))
        if paper_label in variants and error_label in variants:
            items += _relevance_comparison(scene, path, variants[paper_label], variants[error_label])

    hybrid_rows = [row for row in rows if row["mode"] == "HYBRID"]
    if hybrid_rows:
        regret_table = []
        for run, row in ((run, row) for group in groups.values() for run in group
                         for row in rows if row["run"] == run.label and run.mode == "HYBRID"):
            regret = regrets.get(id(run)) or RunRegret(note="not measured")
            regret_table.append([
                run.label, row["variant"], _number(row["budget_ms"], ".1f"), str(regret.frames),
                _number(regret.heuristic_flip, ".4f"), _number(regret.oracle_flip, ".4f"),
                _number(regret.mean, ".4f"), _number(regret.max, ".4f"),
                _number(None if regret.lost_share is None else 100.0 * regret.lost_share, ".0f"), str(regret.differs),
                str(regret.overran), _top(regret.oracle_only), _top(regret.heuristic_only), regret.note])
        every = oracle_results.info.get("every") if oracle_results is not None else oracle.DEFAULT_EVERY
        link = (f" Per frame: [{oracle.REGRET_CSV}]({oracle.REGRET_CSV}); each candidate's measured benefit "
                f"and cost: [{oracle.CANDIDATES_CSV}]({oracle.CANDIDATES_CSV})." if oracle_results is not None else "")
        items.append(("table", _Table(
            "Regret against the oracle",
            ["Run", "Selection", "Budget ms", "Sampled frames", "Heuristic LDR-FLIP", "Oracle LDR-FLIP",
             "Mean regret", "Max regret", "Lost %", "Frames the oracle chose otherwise", "Frames over T",
             "Oracle chose, heuristic did not (frames)", "Heuristic chose, oracle did not (frames)", "Note"],
            regret_table,
            f"Computed after the runs, outside every timed region. On every {every}th frame each visible "
            "candidate is rendered traced alone: its benefit is the drop of the frame's LDR-FLIP against the "
            "reference from the raster frame, its cost the trace stage's measured ms. The oracle takes the "
            "subset with the most benefit whose cost fits the heuristic's time left T in that frame (or, "
            "when the heuristic overran T, what its own choice cost: 'frames over T'), an exact knapsack "
            "(branch and bound), renders it and measures it: regret = LDR-FLIP(heuristic) - LDR-FLIP(oracle). "
            "Lost %: the regret as a share of what the oracle gains over raster, averaged over the sampled "
            "frames where it gains anything (a frame with no time left has nothing to lose). "
            "Benefits only roughly add up (a reflection may show another traced element), so a regret "
            "slightly below 0 is possible." + link)))

    pop_rows = []
    for group in groups.values():
        for run in group:
            pop = pops.get(id(run))
            if pop is None:
                continue
            per_element = pop.per_element()
            worst = sorted(per_element.items(), key=lambda item: (-item[1][1], item[0]))[:WORST_ELEMENTS]
            rates = np.array(list(runlog.flips_per_element_per_100(run.selection).values()), dtype=float)
            pop_rows.append([
                run.label, run.mode.lower(), str(len(pop.pops)),
                _number(float(rates.mean()) if rates.size else None, ".2f"),
                _number(pop.per_100_frames(), ".4f"),
                _number(float(np.mean([p.popping for p in pop.pops])) if pop.pops and pop.measured else None, ".4f"),
                ", ".join(f"{name} ({flips} flips, {total:+.3f})" for name, (flips, total) in worst
                          if pop.measured) or "none",
                pop.note or ("reference" if run.mode == "RAYTRACE" and not pop.pops else "")])
    if pop_rows:
        items.append(("table", _Table(
            "Popping",
            ["Run", "Mode", "Flips", "Flips / element / 100 frames", "Popping / 100 frames", "Mean per flip",
             "Worst elements (flips, summed popping)", "Note"], pop_rows,
            "For each element whose traced state flipped between consecutive frames: LDR-FLIP between the "
            "two frames inside the element's pixels (either frame's), minus the same in the reference run. "
            "About 0: the switch does not show beyond the camera's motion (an element entering or leaving "
            "the view flips too, and pops as much as the reference changes); positive: a visible pop. "
            "Popping / 100 frames sums every flip's popping per 100 frames of the run.")))
    if files.selection_quality_png is not None:
        items.append(("img", files.selection_quality_png.name,
                      "Mean regret against the oracle (left) and popping per 100 frames (right) against the "
                      "frame budget, one curve per selection variant."))
    return items


def relevance_verdict(paper, error):
    """Which relevance wins over the budgets both ran ({budget_at: sweep row}): the mean LDR-FLIP
    over those budgets (the area under each curve), the budgets where each is lower, and the
    mean regret.  Returns (text, relative change of the mean LDR-FLIP or None)."""
    shared = sorted(fraction for fraction in set(paper) & set(error)
                    if paper[fraction]["flip"] is not None and error[fraction]["flip"] is not None)
    if not shared:
        return "the two relevances could not be compared (no error measured).", None
    flip_paper = float(np.mean([paper[f]["flip"] for f in shared]))
    flip_error = float(np.mean([error[f]["flip"] for f in shared]))
    lower = sum(1 for f in shared if error[f]["flip"] < paper[f]["flip"])
    higher = sum(1 for f in shared if error[f]["flip"] > paper[f]["flip"])
    change = (flip_error - flip_paper) / flip_paper if flip_paper > 0 else None
    if flip_error == flip_paper:
        head = "neither relevance wins"
    else:
        head = f"the {'error-aware' if flip_error < flip_paper else 'paper'} relevance wins"
    text = (f"{head}: mean LDR-FLIP over the {len(shared)} budget(s) {flip_paper:.4f} with the paper's R, "
            f"{flip_error:.4f} with the error-aware R"
            + (f" ({100 * change:+.1f}%)" if change is not None else "")
            + f"; the error-aware R is lower at {lower} and higher at {higher} of them")
    regrets = [(paper[f]["regret"], error[f]["regret"]) for f in shared
               if paper[f]["regret"] is not None and error[f]["regret"] is not None]
    if regrets:
        text += (f"; mean regret {np.mean([a for a, _ in regrets]):.4f} (paper R) against "
                 f"{np.mean([b for _, b in regrets]):.4f} (error-aware R)")
    shares = [(paper[f]["regret_share"], error[f]["regret_share"]) for f in shared
              if paper[f].get("regret_share") is not None and error[f].get("regret_share") is not None]
    if shares:
        text += (f", losing {100 * np.mean([a for a, _ in shares]):.0f}% against "
                 f"{100 * np.mean([b for _, b in shares]):.0f}% of what the oracle gains over raster")
    return text + ".", change


def _relevance_comparison(scene, path, paper, error):
    """The paper's relevance against the error-aware one at each budget both ran."""
    table = []
    for fraction in sorted(set(paper) & set(error)):
        a, b = paper[fraction], error[fraction]
        change = None
        if a["flip"] and b["flip"] is not None:
            change = 100.0 * (b["flip"] - a["flip"]) / a["flip"]
        table.append([f"{fraction:.2f}", _number(a["budget_ms"], ".1f"), _number(a["flip"], ".4f"),
                      _number(b["flip"], ".4f"), _signed(change, ".1f") + ("%" if change is not None else ""),
                      _number(a["regret"], ".4f"), _number(b["regret"], ".4f"),
                      _number(a["popping"], ".4f"), _number(b["popping"], ".4f")])
    verdict, _ = relevance_verdict(paper, error)
    return [("table", _Table(
        f"Paper relevance against error-aware relevance: {scene} / {path}",
        ["Budget at", "Budget ms", "LDR-FLIP, paper R", "LDR-FLIP, error-aware R", "Change",
         "Regret, paper R", "Regret, error-aware R", "Popping / 100, paper R", "Popping / 100, error-aware R"],
        table,
        "Both with the measured cost model, I = 0.5 and the paper's greedy order; the error-aware relevance "
        "weights V by each element's running estimate of its traced-vs-raster difference per pixel "
        f"(a prior from its material before it is first traced). On {scene} / {path}, " + verdict))]


def _markdown_cell(text):
    return str(text).replace("|", "\\|").replace("\n", " ")


def _markdown(items):
    lines = []
    for item in items:
        kind = item[0]
        if kind == "h1":
            lines += [f"# {item[1]}", ""]
        elif kind == "p":
            lines += [item[1], ""]
        elif kind == "img":
            lines += [f"![{item[2]}]({item[1]})", "", f"*{item[2]}*", ""]
        else:
            table = item[1]
            lines += [f"## {table.title}", ""]
            if table.intro:
                lines += [table.intro, ""]
            lines.append("| " + " | ".join(_markdown_cell(h) for h in table.header) + " |")
            lines.append("|" + "|".join("---" for _ in table.header) + "|")
            lines += ["| " + " | ".join(_markdown_cell(c) for c in row) + " |" for row in table.rows]
            lines.append("")
    return "\n".join(lines)


_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:0.5em 0 1.5em}"
        "th,td{border:1px solid #bbb;padding:3px 8px;text-align:right}"
        "th{background:#eee}td:first-child,th:first-child{text-align:left}"
        "img{max-width:100%}figcaption{font-style:italic;margin-bottom:1.5em}")


def _html(items):
    escape = html.escape
    body = []
    for item in items:
        kind = item[0]
        if kind == "h1":
            body.append(f"<h1>{escape(item[1])}</h1>")
        elif kind == "p":
            body.append(f"<p>{escape(item[1])}</p>")
        elif kind == "img":
            body.append(f'<figure><img src="{escape(item[1])}" alt="{escape(item[2])}">'
                        f"<figcaption>{escape(item[2])}</figcaption></figure>")
        else:
            table = item[1]
            body.append(f"<h2>{escape(table.title)}</h2>")
            if table.intro:
                body.append(f"<p>{_html_links(escape(table.intro))}</p>")
            head = "".join(f"<th>{escape(h)}</th>" for h in table.header)
            rows = "".join("<tr>" + "".join(f"<td>{escape(str(c))}</td>" for c in row) + "</tr>"
                           for row in table.rows)
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>")
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>PHRT report</title>"
            f"<style>{_CSS}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def _html_links(text):
    """Turn the markdown link ``[name](name)`` of an escaped paragraph into <a>."""
    return re.sub(r"\[([^\]]+)\]\(([^)]+)\)", r'<a href="\2">\1</a>', text)
