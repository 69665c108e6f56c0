"""The names PHRT's files, properties and command line share: one place for each.

Modes, selection variants, render passes, the columns of ``frames.csv`` and
``selection.csv``, the reasons an element was not traced and the files of a run
directory.  Everything else imports them from here; ``docs/formats.md``
describes each file and column, ``docs/properties.md`` each property.
Declarations only: no logic.
"""
from __future__ import annotations

# -- render modes ------------------------------------------------------------------------
RASTER, HYBRID, RAYTRACE = "RASTER", "HYBRID", "RAYTRACE"
MODES = (RASTER, HYBRID, RAYTRACE)
# (identifier, title, what it does): Scene.phrt.mode items, report titles, CLI help.
MODE_ITEMS = (
    (RASTER, "Raster", "Raster only: G-buffer, shadow maps and blending; no ray tracing at all"),
    (HYBRID, "Hybrid", "Raster plus ray tracing of the elements the heuristic selects within the budget"),
    (RAYTRACE, "Ray Trace", "Ray trace every visible candidate with no budget: the reference image"),
)
MODE_TITLES = {RASTER: "Raster", HYBRID: "Hybrid", RAYTRACE: "Ray tracing"}  # report tables
# The order a replay of several modes runs them in: the budget of HYBRID between modes
# (``budget_at``) is resolved from the RASTER and RAYTRACE runs beside it.
REPLAY_ORDER = (RASTER, RAYTRACE, HYBRID)

# -- selection variants (Scene.phrt enums; lower case in the heuristic and plan.json) ---
COST_MODE_ITEMS = (
    ("PAPER", "Paper", "C = V * Q, scaled to milliseconds by a factor fitted to measured trace times"),
    ("MEASURED", "Measured", "Predicted from the element's pixel count and the measured cost per ray of "
                             "its effects, times Q"),
)
RELEVANCE_ITEMS = (
    ("PAPER", "Paper", "R = (S * I + V) * K, the paper's equation (3)"),
    ("ERROR", "Error-Aware", "V weighted by a running estimate of the element's traced-vs-raster "
                             "difference per pixel (a prior from its material before it is traced)"),
)
SELECTION_ITEMS = (
    ("PAPER", "Paper", "The paper's heuristic: the most relevant elements whose cost fits the time left"),
    ("BENEFIT", "Benefit per ms", "(element, effect) items valued by the error they remove, learned per item, "
                                  "chosen by an exact knapsack within the time left, with a switching cost"),
)
ORDER_ITEMS = (
    ("RELEVANCE", "Relevance", "The paper's: the most relevant element first"),
    ("RELEVANCE_PER_MS", "Relevance per ms", "Relevance divided by the predicted milliseconds first"),
)
COST_MODES = tuple(item[0].lower() for item in COST_MODE_ITEMS)
RELEVANCES = tuple(item[0].lower() for item in RELEVANCE_ITEMS)
ORDERS = tuple(item[0].lower() for item in ORDER_ITEMS)
SELECTIONS = tuple(item[0].lower() for item in SELECTION_ITEMS)

# -- ray traced effects an element may get ---------------------------------------------
EFFECTS = ("shadows", "reflections", "refractions")

# -- render passes (besides Combined and Depth, registered by the engine) ----------------
COMBINED_PASS = "Combined"
DEPTH_PASS = "Depth"
ELEMENT_PASS = "PHRT Element"
# name, channels, channel ids, type (RenderEngine.register_pass), in the order written.
PASSES = (
    (COMBINED_PASS, 4, "RGBA", "COLOR"),
    (DEPTH_PASS, 1, "Z", "VALUE"),
    ("Normal", 3, "XYZ", "VECTOR"),
    ("PHRT Selected", 1, "X", "VALUE"),  # 1 where the front element was ray traced this frame
    ("PHRT Candidate", 1, "X", "VALUE"),  # 1 on every candidate element's pixels
    (ELEMENT_PASS, 1, "X", "VALUE"),  # front element index + 1, 0 where none (popping, report)
    ("PHRT Rate", 1, "X", "VALUE"),  # the rate the pixel's traced terms came at (1, 0.5, 0.25), 0: raster
)
# Pass name -> attribute of ``frame.FramePasses``.
PASS_FIELDS = {COMBINED_PASS: "combined", DEPTH_PASS: "depth", "Normal": "normal", "PHRT Selected": "selected",
               "PHRT Candidate": "candidate", ELEMENT_PASS: "element", "PHRT Rate": "rate"}

# -- a run directory (docs/formats.md) ---------------------------------------------------
FRAMES_CSV = "frames.csv"
SELECTION_CSV = "selection.csv"
SUMMARY_JSON = "summary.json"
FRAMES_DIR = "frames"

FRAME_COLUMNS = (
    "frame", "mode", "total_ms", "raster_ms", "select_ms", "trace_ms",
    "composite_ms", "budget_ms", "predicted_trace_ms", "n_candidates",
    "n_visible", "n_selected", "rays",
)
# Written after FRAME_COLUMNS by a replay (engine/runs/replay.py).
EXTRA_FRAME_COLUMNS = ("wall_ms", "extract_ms", "gbuffer_ms", "readback_ms", "lighting_ms", "upload_ms", "setup_ms",
                       "shadow_rays", "reflection_rays", "refraction_rays", "time_left_ms", "triangles")
# A column under an older name, written as a copy of the stat it always was: frames.csv keeps
# ``lighting_ms`` (docs/formats.md), the lighting and composite passes, i.e. ``composite_ms``.
COPIED_FRAME_COLUMNS = {"lighting_ms": "composite_ms"}
STAGE_COLUMNS = ("raster_ms", "select_ms", "trace_ms", "composite_ms")
SELECTION_COLUMNS = (
    "frame", "element", "visible", "A", "P", "D", "V", "Q", "C", "K", "S", "R",
    "selected", "reason",
)
# Why an element was not ray traced; empty when it was selected.
REASONS = ("not_visible", "over_area", "over_budget", "not_candidate")
STRING_COLUMNS = frozenset({"mode", "element", "reason", "effects"})
BOOL_COLUMNS = frozenset({"visible", "selected"})
