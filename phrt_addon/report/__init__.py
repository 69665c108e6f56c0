"""The report of several runs of a camera path (``phrt report``, docs/formats.md).

:func:`build_report` reads RUN_DIRs (see :mod:`.runlog`) and writes into
``out_dir``:

- ``report.md`` and ``report.html``: first the error-time curve and, per
  budget, the selection variants side by side (``results.py``: the captured
  share of the oracle's error reduction with its 90% interval from
  ``captured.py``, LDR-FLIP, popping, p95 / budget, within budget; a
  difference named only where intervals do not overlap), then a table in the style of the paper's
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
folder computed from them (``phrt_addon/report/oracle.py``), the report adds the
heuristic's regret against the oracle selection; popping
(``phrt_addon/report/popping.py``) is measured for every run with EXR images.  Table
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

Modules: ``runs`` (loading, references, errors, Pareto front), ``selection`` (popping,
regret, sweep rows), ``plots``, ``document`` (the sections), ``markup`` (Markdown and
HTML), ``build`` (``build_report``: all of it in order).
"""
from .build import build_report
from .document import SWEEP_TABLE_FORMATS, SWEEP_TABLE_TITLE, relevance_verdict, table_ii_hybrid, table_ii_rows
from .runs import (ERROR_COLUMNS, PAPER_SCENES, PAPER_TABLE_II, SWEEP_COLUMNS, ReportFiles, Run, RunErrors,
                   load_run, pareto_front)
from .selection import RunRegret, sweep_rows, variant_label

__all__ = ["build_report", "SWEEP_TABLE_FORMATS", "SWEEP_TABLE_TITLE", "relevance_verdict", "table_ii_hybrid",
           "table_ii_rows", "ERROR_COLUMNS", "PAPER_SCENES", "PAPER_TABLE_II", "SWEEP_COLUMNS", "ReportFiles", "Run",
           "RunErrors", "load_run", "pareto_front", "RunRegret", "sweep_rows", "variant_label"]
