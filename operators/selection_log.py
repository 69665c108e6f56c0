"""``phrt.export_selection_log``: the heuristic's decisions of the last rendered frame
(or of a whole replay's ``selection.csv``) as a CSV or JSON file.

CSV has the CONTRACT columns of ``selection.csv`` (section 4) first, then any extra
ones, numbers written like the run logs (6 significant digits, booleans 1/0).
JSON is a list of one object per row with the same keys (booleans as true/false,
non-finite numbers as null).  The format follows the file's extension.
"""

import csv
import json
from pathlib import Path

import bpy
from bpy.props import StringProperty

from ..engine import session
from ..phrt_addon.runs import run_log
from ..phrt_addon import schema
from ..phrt_addon.runs import run_files
from ..properties import BLEND_RELATIVE_PATH

FORMATS = (".csv", ".json")
_BOOL_COLUMNS = ("visible", "selected")


class SelectionLogError(ValueError):
    """What is wrong with the request, and how to fix it."""


def _columns(rows) -> list:
    columns = list(schema.SELECTION_COLUMNS)
    for row in rows:
        columns += [key for key in row if key not in columns]
    return columns


def _json_value(column, value):
    if column in _BOOL_COLUMNS and value is not None:
        return bool(value)
    if column in ("element", "reason"):
        return "" if value is None else str(value)
    return run_log.finite_or_none(value)


def write_selection_log(rows, filepath) -> Path:
    """Write ``rows`` (selection rows: dicts with the CONTRACT columns) to ``filepath``,
    CSV or JSON by its extension; returns the path written."""
    path = Path(filepath)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise SelectionLogError(f"cannot export to '{path.name}': the file name must end in .csv or .json")
    rows = list(rows)
    if not rows:
        raise SelectionLogError("no selection rows to export: render a frame with PHRT first (F12), "
                                "or give the run folder of a replay")
    columns = _columns(rows)
    if not path.parent.is_dir():
        raise SelectionLogError(f"cannot write '{path}': the folder '{path.parent}' does not exist")
    try:
        if suffix == ".csv":
            with open(path, "w", newline="", encoding="utf-8") as handle:
                writer = csv.writer(handle, lineterminator="\n")
                writer.writerow(columns)
                writer.writerows([run_log.format_value(row.get(column)) for column in columns] for row in rows)
        else:
            data = [{column: _json_value(column, row.get(column)) for column in columns} for row in rows]
            path.write_text(json.dumps(data, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    except OSError as error:
        raise SelectionLogError(f"cannot write '{path}': {error.strerror or error}") from None
    return path


def rows_to_export(run_dir: str = "") -> list:
    """The last rendered frame's rows, or every frame's rows of the replay in ``run_dir``."""
    if not run_dir:
        return list(session.last_frame().rows)
    folder = Path(bpy.path.abspath(run_dir))
    if not (folder / schema.SELECTION_CSV).is_file():
        raise SelectionLogError(f"'{run_dir}' is not a run folder (no {schema.SELECTION_CSV}): give a folder "
                                f"written by phrt.replay_path or 'phrt render'")
    return run_files.read_selection(folder)


class PHRT_OT_export_selection_log(bpy.types.Operator):
    """Write the heuristic's decisions (V, C, R, selected or why not, per element) of the last
    rendered frame, or of every frame of a replay, to a .csv or .json file"""

    bl_idname = "phrt.export_selection_log"
    bl_label = "Export Selection Log"
    bl_options = {"REGISTER"}

    filepath: StringProperty(
        name="File", subtype="FILE_PATH", options=BLEND_RELATIVE_PATH,
        description="Where to write the log; its extension (.csv or .json) chooses the format",
    )
    run_dir: StringProperty(
        name="Run Folder", subtype="DIR_PATH", options=BLEND_RELATIVE_PATH,
        description="Export the selection.csv rows of this replay's run folder instead of the last rendered frame",
    )
    filter_glob: StringProperty(default="*.csv;*.json", options={"HIDDEN"})

    def invoke(self, context, event):
        if not self.filepath:
            self.filepath = bpy.path.ensure_ext(bpy.path.abspath("//phrt_selection"), ".csv")
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        try:
            path = write_selection_log(rows_to_export(self.run_dir), bpy.path.abspath(self.filepath))
        except SelectionLogError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self.report({"INFO"}, f"PHRT: selection log written to {path}")
        return {"FINISHED"}


CLASSES = (PHRT_OT_export_selection_log,)
