"""``build_report``: reads the runs, measures errors, regret and popping, writes every file of the report.
"""
from pathlib import Path

from . import oracle
from ..runs import atomic
from .document import report_sections
from .markup import ReportTable, to_html, to_markdown
from .plots import plot_error_vs_time, plot_selection_quality, plot_timeline
from .runs import ReportFiles, measure_group, find_references, unique_labels, write_errors_csv, load_run
from .selection import measure_run_popping, load_oracle_results, run_regrets, write_sweep, sweep_rows


def build_report(run_dirs, reference=None, out_dir="out/report", oracle_dir=None, failures=()):
    """Write the report of ``run_dirs`` into ``out_dir``; returns :class:`ReportFiles`.

    ``reference`` is a RUN_DIR (added to the runs if it is not among them);
    by default each path's raytrace run.  ``oracle_dir`` is an oracle folder
    (``phrt_addon/report/oracle.py``); by default the ``oracle`` folder beside the runs,
    when they share one parent folder.  ``failures`` are (job, one-line message)
    pairs of a plan's jobs that failed, listed first.  Raises ``ValueError`` with
    a message for the user when a RUN_DIR is unusable or there is no reference at all.
    """
    paths = []
    for run_dir in list(run_dirs) + ([reference] if reference is not None else []):
        if Path(run_dir).resolve() not in [p.resolve() for p in paths]:
            paths.append(Path(run_dir))
    if not paths:
        raise ValueError("no RUN_DIR given")
    # A lockstep sweep's group raster run only times the oracle's shared part: never "the raster run".
    runs = [run for run in (load_run(path) for path in paths) if not run.summary.get("group_raster")]
    if not runs:
        raise ValueError("the RUN_DIRs hold only a lockstep sweep's group raster run: give the sweep's runs")
    unique_labels(runs)
    reference_run = None
    if reference is not None:
        reference_run = next(run for run in runs if run.run_dir.resolve() == Path(reference).resolve())
    groups = {}
    for run in runs:
        groups.setdefault(run.group, []).append(run)
    references = find_references(groups, reference_run)

    errors = {}
    for group, members in groups.items():
        errors.update(measure_group(members, references[group]))

    pops = measure_run_popping(runs, references)
    oracle_results = load_oracle_results(runs, oracle_dir)
    regrets = run_regrets(runs, oracle_results)

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = ReportFiles(markdown=out_dir / "report.md", html=out_dir / "report.html",
                        errors_csv=out_dir / "errors.csv",
                        error_vs_time_png=out_dir / "error_vs_time.png",
                        timeline_png=out_dir / "timeline.png",
                        sweep_csv=out_dir / "sweep.csv", sweep_json=out_dir / "sweep.json")
    rows = sweep_rows(runs, errors, regrets, pops, references)
    write_errors_csv(files.errors_csv, runs, errors)
    write_sweep(files.sweep_csv, files.sweep_json, rows, oracle_results)
    files.figures[files.error_vs_time_png.name] = plot_error_vs_time(files.error_vs_time_png, groups, errors)
    files.figures[files.timeline_png.name] = plot_timeline(files.timeline_png, groups)
    if any(run.mode == "HYBRID" for run in runs):
        files.selection_quality_png = out_dir / "selection_quality.png"
        files.figures[files.selection_quality_png.name] = plot_selection_quality(
            files.selection_quality_png, groups, regrets, pops)
    if oracle_results is not None:
        oracle.write_csv(out_dir / oracle.REGRET_CSV, oracle.REGRET_COLUMNS,
                         [{**row, **{key: ";".join(row[key]) for key in ("heuristic", "oracle", "oracle_only",
                                                                         "heuristic_only")}}
                          for row in oracle_results.regret_rows])
        oracle.write_csv(out_dir / oracle.CANDIDATES_CSV, ("sweep",) + oracle.CANDIDATE_COLUMNS,
                         oracle_results.candidate_rows)
    sections = report_sections(runs, groups, references, errors, files, rows=rows, regrets=regrets, pops=pops,
                         oracle_results=oracle_results)
    if failures:
        sections[2:2] = [("table", ReportTable(
            "Failed jobs", ["Job", "Why"], [[job, message] for job, message in failures],
            "Jobs of the plan that ended without a result (after their retries); the report covers the "
            "others. Running the plan again retries them."))]
    atomic.write_text(files.markdown, to_markdown(sections))
    atomic.write_text(files.html, to_html(sections))
    return files
