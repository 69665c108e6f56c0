"""The report of several runs of a camera path (``phrt report``, CONTRACT.md section 5).

:func:`build_report` reads RUN_DIRs (see :mod:`.runlog`) and writes into
``out_dir``:

- ``report.md`` and ``report.html``: a table in the style of the paper's
  Table II (mean ms per frame of the raster, hybrid and raytrace runs, one row
  per (scene, path)), a table of every run (frame time statistics, stages,
  budget), the error of every run against the reference run (mean LDR-FLIP,
  relMSE, PSNR averaged over frames), selection stability (selection flips per
  element per 100 frames, and the worst elements), and the machine;
- ``errors.csv``: the error of every compared frame;
- ``error_vs_time.png``: mean LDR-FLIP against mean frame time, one labelled
  point per run, the Pareto front of each path drawn;
- ``timeline.png``: per frame, the frame time of each run with the budget line,
  and the number of selected elements below.

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
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import metrics, runlog

MODES = ("RASTER", "HYBRID", "RAYTRACE")
MODE_TITLES = {"RASTER": "Raster", "HYBRID": "Hybrid", "RAYTRACE": "Ray tracing"}
ERROR_COLUMNS = ("scene", "path", "run", "mode", "reference", "frame", "flip", "relmse", "psnr_db")
WORST_ELEMENTS = 3


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
    for frame in frames:
        reference_path = reference.image(frame)
        pending = [run for run in compared if run.image(frame) is not None
                   and not results[id(run)].note]
        if reference_path is None or not pending:
            continue
        reference_image = metrics.read_image(reference_path)  # unreadable: ValueError for the user
        for run in pending:
            try:
                errors = metrics.image_errors(reference_image, metrics.read_image(run.image(frame)))
            except ValueError as error:
                results[id(run)].note = f"not compared: {error}"
                results[id(run)].per_frame.clear()
                continue
            results[id(run)].per_frame.append({"frame": frame, **errors})
    for run in compared:
        outcome = results[id(run)]
        if not outcome.note:
            frame_count = len({row["frame"] for row in run.frames})
            if not outcome.per_frame:
                outcome.note = "no frame in common with the reference"
            elif len(outcome.per_frame) < frame_count:
                outcome.note = f"{len(outcome.per_frame)} of {frame_count} frames compared"
    return results


def build_report(run_dirs, reference=None, out_dir="out/report"):
    """Write the report of ``run_dirs`` into ``out_dir``; returns :class:`ReportFiles`.

    ``reference`` is a RUN_DIR (added to the runs if it is not among them);
    by default each path's raytrace run.  Raises ``ValueError`` with a message
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

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = ReportFiles(markdown=out_dir / "report.md", html=out_dir / "report.html",
                        errors_csv=out_dir / "errors.csv",
                        error_vs_time_png=out_dir / "error_vs_time.png",
                        timeline_png=out_dir / "timeline.png")
    _write_errors_csv(files.errors_csv, runs, errors)
    _plot_error_vs_time(files.error_vs_time_png, groups, errors)
    _plot_timeline(files.timeline_png, groups)
    sections = _sections(runs, groups, references, errors, files)
    files.markdown.write_text(_markdown(sections), encoding="utf-8")
    files.html.write_text(_html(sections), encoding="utf-8")
    return files


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
    """One panel per (scene, path): errors of different paths do not compare."""
    columns = min(2, len(groups))
    rows = -(-len(groups) // columns)
    figure = _figure(figsize=(8 * columns, 5.5 * rows))
    panels = figure.subplots(rows, columns, squeeze=False).ravel()
    for axes in panels[len(groups):]:
        axes.set_visible(False)
    for axes, (group, members) in zip(panels, groups.items()):
        _plot_error_vs_time_panel(axes, group, members, errors)
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def _plot_error_vs_time_panel(axes, group, members, errors):
    axes.set_title(f"{group[0]} / {group[1]}: error against frame time")
    axes.set_xlabel("mean frame time (ms)")
    axes.set_ylabel("mean LDR-FLIP against the reference (lower is better)")
    axes.grid(True, alpha=0.3)
    points = [(run, run.mean("total_ms"), errors[id(run)].mean("flip")) for run in members]
    points = sorted(((run, time, error) for run, time, error in points
                     if time is not None and error is not None), key=lambda p: (p[1], p[2]))
    if not points:
        axes.text(0.5, 0.5, "no error measured for this path\n(see the error table)",
                  ha="center", va="center", transform=axes.transAxes)
        return
    times = np.array([time for _, time, _ in points])
    flips = np.array([error for _, _, error in points])
    axes.scatter(times, flips, color="tab:blue", zorder=3, label="run")
    # Neighbours' labels alternate above and below their points (never below the axis).
    for rank, (run, time, error) in enumerate(points):
        below = rank % 2 == 1 and error > 0.15 * flips.max()
        axes.annotate(f"{run.label}\n({run.mode.lower()})", (time, error), fontsize=8,
                      textcoords="offset points", xytext=(6, -22 if below else 6))
    front = pareto_front(times, flips)
    axes.plot(times[front], flips[front], color="tab:blue", drawstyle="steps-post",
              linestyle="--", linewidth=1.2, label="Pareto front")
    budgets = sorted({run.summary.get("budget_ms") for run, _, _ in points
                      if run.mode == "HYBRID" and run.summary.get("budget_ms")})
    for budget in budgets:
        axes.axvline(budget, color="tab:red", linestyle=":", linewidth=1.0)
        axes.annotate(f"budget {budget:g} ms", (budget, 0.0), xycoords=("data", "axes fraction"),
                      xytext=(3, 4), textcoords="offset points", fontsize=8, color="tab:red",
                      rotation=90, va="bottom")
    # Room on the right and at the top for the point labels.
    axes.set_xlim(0.0, 1.3 * max(float(times.max()), *budgets, 1.0))
    axes.set_ylim(0.0, 1.25 * float(flips.max()) if flips.max() > 0 else 1.0)
    axes.legend(fontsize=8, loc="upper right")


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


def _sections(runs, groups, references, errors, files):
    """The report as a list of items: ('h', text), ('p', text), ('table', _Table), ('img', file)."""
    items = [("h1", "PHRT report")]
    items.append(("p", f"{len(runs)} runs of {len(groups)} camera path(s). Frame times are "
                       f"means over the frames of each run, in milliseconds."))

    table2 = []
    for (scene, path), members in groups.items():
        cells = []
        for mode in MODES:
            values = [_ms(run.mean("total_ms")) for run in members if run.mode == mode]
            cells.append(" / ".join(values) if values else "–")
        table2.append([scene, path] + cells)
    items.append(("table", _Table(
        "Render times (ms per frame), after the paper's Table II",
        ["Scene", "Path"] + [f"{MODE_TITLES[mode]} rendering" for mode in MODES], table2,
        "Mean time to render a frame of the path in each mode; several runs of one mode "
        "are separated by ' / '.")))

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
                  "Mean LDR-FLIP against mean frame time; dashed: Pareto front of each path."))
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
