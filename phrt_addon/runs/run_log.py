"""Run logs: the files a replay writes into its RUN_DIR (readers in ``run_files.py``).

A RUN_DIR (docs/formats.md) holds

- ``frames.csv``: one row per frame (timings of each stage, the budget, counts);
- ``selection.csv``: one row per (frame, element): the heuristic's inputs
  (A, P, D, V, Q, C, K, S, R), whether the element was selected and why not;
- ``summary.json``: statistics of the run, the versions and the machine.

:class:`RunLog` writes them one frame at a time and flushes both CSVs after
every frame.  Given the run's facts when it opens (``facts``), it writes
``summary.json`` at once with ``"partial": true`` and ``frame_count`` 0, and
rewrites it as frames complete (at most once a second, and once a frame when
frames take longer: whichever is rarer), then a last time at :meth:`close`.
``summary.json`` is the commit record: the readers (``run_files.py``) read the
first ``frame_count`` rows of ``frames.csv``, the selection rows of those frames
and their images only, so a run killed at any moment (SIGKILL, a power cut)
reads back consistently: the frames done when the summary was last written.
A frame's image is renamed into place before its rows are written, and its
selection rows before its frame row.  Every ``summary.json`` is written under a
temporary name with this host and pid (``runs/atomic.py``) and renamed.

No NaN or Inf reaches a log: a non-finite number is written as an empty cell
(read back as ``None``) and counted in ``summary.json`` under
``non_finite_values_dropped``.  Floats are written with 6 significant digits.

Plain Python, no ``bpy``: the caller passes the Blender and embreex versions.
"""
import csv
import json
from array import array
import logging
import math
import os
import time
from numbers import Integral, Real
from pathlib import Path

import numpy as np

from . import atomic
from .summary import machine_info, summarize
from ..schema import FRAME_COLUMNS, FRAMES_CSV, REASONS, SELECTION_COLUMNS, SELECTION_CSV, SUMMARY_JSON


log = logging.getLogger(__name__)

# Keys of summary.json the caller must pass to close() (the rest is computed).
SUMMARY_REQUIRED_KEYS = ("scene", "path", "resolution", "blender_version", "embreex_version")
SIGNIFICANT_DIGITS = 6
SUMMARY_EVERY_S = 1.0  # the partial summary is rewritten at most this often


def format_value(value):
    """One CSV cell: ints as ints, floats with 6 significant digits, bools as 1/0.

    ``None`` and non-finite floats become the empty cell.
    """
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "1" if value else "0"
    if isinstance(value, Integral):
        return str(int(value))
    if isinstance(value, Real):
        number = float(value)
        if not math.isfinite(number):
            return ""
        text = format(number, f".{SIGNIFICANT_DIGITS}g")
        return "0" if text == "-0" else text
    return str(value)


def _is_non_finite(value):
    return (isinstance(value, Real) and not isinstance(value, (bool, np.bool_, Integral))
            and not math.isfinite(float(value)))


def finite_or_none(value):
    """``value`` as a JSON-safe number: ``None`` for NaN/Inf, numpy scalars unwrapped."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, Integral):
        return int(value)
    if isinstance(value, Real):
        number = float(value)
        return number if math.isfinite(number) else None
    return value


def _json_safe(value):
    if isinstance(value, dict):
        return {str(key): _json_safe(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(item) for item in value]
    if isinstance(value, np.ndarray):
        return [_json_safe(item) for item in value.tolist()]
    return finite_or_none(value)


def _round_json(value):
    """Round every float of a JSON-safe structure to 6 significant digits."""
    if isinstance(value, dict):
        return {key: _round_json(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_round_json(item) for item in value]
    if isinstance(value, float):
        return float(format(value, f".{SIGNIFICANT_DIGITS}g"))
    return value


def json_ready(value):
    """``value`` as PHRT writes a JSON document: every number finite or null, floats rounded to
    6 significant digits, numpy arrays as lists, keys as strings."""
    return _round_json(_json_safe(value))


class _CsvTable:
    """One CSV file with a fixed header, written row by row."""

    def __init__(self, path, required, extra):
        self.path = Path(path)
        self.required = tuple(required)
        self.extra = None if extra is None else tuple(extra)
        self.columns = None
        self.non_finite = 0
        self._warned = set()
        self._file = open(self.path, "w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._file, lineterminator="\n")

    def _fix_header(self, first_row):
        if self.extra is None:
            self.extra = tuple(key for key in first_row if key not in self.required)
        self.columns = self.required + tuple(k for k in self.extra if k not in self.required)
        self._writer.writerow(self.columns)

    def check(self, rows):
        """``ValueError`` if a row misses a required column or has an unknown one."""
        if self.columns is None:
            self._fix_header(rows[0] if rows else {})
        for row in rows:
            missing = [key for key in self.required if key not in row]
            if missing:
                raise ValueError(f"{self.path.name}: row misses the columns {missing}")
            unknown = [key for key in row if key not in self.columns]
            if unknown:
                raise ValueError(
                    f"{self.path.name}: unknown columns {unknown}; declare extra columns "
                    f"when opening the RunLog or put them in the first row")

    def write(self, rows):
        """Write ``rows`` after checking all of them (a bad row writes nothing)."""
        self.check(rows)
        for row in rows:
            for key in self.columns:
                if _is_non_finite(row.get(key)):
                    self.non_finite += 1
                    if key not in self._warned:  # once per column; summary.json has the count
                        self._warned.add(key)
                        log.warning("%s: non-finite %s=%r in frame %s written as empty (further ones are "
                                    "counted in summary.json)", self.path.name, key, row.get(key), row.get("frame"))
        self._writer.writerows([format_value(row.get(key)) for key in self.columns] for row in rows)

    def flush(self):
        if self.columns is None:
            self._fix_header({})
        self._file.flush()

    def close(self):
        if not self._file.closed:
            self.flush()
            self._file.close()

    def abandon(self):
        """Close without writing what is still buffered (after a write error)."""
        if not self._file.closed:
            try:
                os.close(self._file.fileno())
            except OSError:
                pass
            try:
                self._file.close()
            except (OSError, ValueError):
                pass


class RunLog:
    """Writes the logs of one replay into ``run_dir``.

    Usage::

        log = RunLog(run_dir)
        for each frame:
            log.add_frame(frame_row, selection_rows)   # both CSVs flushed
        log.close({"scene": ..., "path": ..., "mode": ..., "resolution": (w, h),
                   "budget_ms": ..., "blender_version": ..., "embreex_version": ...})

    ``frame_row`` needs every column of :data:`FRAME_COLUMNS`, each selection
    row every column of :data:`SELECTION_COLUMNS`.  Extra columns come after
    the contract's; they are fixed when the header is written (the first
    frame), from ``extra_frame_columns`` / ``extra_selection_columns`` or else
    from the keys of the first row.  Existing logs in ``run_dir`` are replaced.
    """

    def __init__(self, run_dir, extra_frame_columns=None, extra_selection_columns=None, facts=None,
                 summary_every_s=SUMMARY_EVERY_S, clock=time.monotonic):
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        if facts is None:
            (self.run_dir / SUMMARY_JSON).unlink(missing_ok=True)  # first: the folder stops being a run
        # What summary.json needs, kept compact (a 1000-frame replay must not grow with its length
        # more than it must): one tuple per frame, per element its frames and selected flags.
        self._frame_values = []
        self._selection_states = {}  # element -> (array of frames, bytearray of selected flags)
        self._closed = False
        self._facts = None if facts is None else dict(facts)
        self._summary_every_s = float(summary_every_s)
        self._clock = clock
        self._summary_written_at = None
        self._selection = self._frames = None
        self.summaries_written = 0
        if self._facts is not None:  # the run exists (0 frames) before its logs do
            self._check_facts(self._facts)
            self.write_partial_summary()
        self._selection = _CsvTable(self.run_dir / SELECTION_CSV, SELECTION_COLUMNS,
                                    extra_selection_columns)
        self._frames = _CsvTable(self.run_dir / FRAMES_CSV, FRAME_COLUMNS, extra_frame_columns)
        for table in (self._selection, self._frames):
            if table.extra is not None:
                table.flush()  # the header now: its columns are known

    @property
    def frame_count(self):
        return len(self._frame_values)

    def add_frame(self, frame_row, selection_rows=()):
        """Append one frame (and its selection rows) and flush both CSVs."""
        if self._closed:
            raise ValueError("RunLog is closed")
        frame = frame_row.get("frame")
        if not isinstance(frame, Integral) or isinstance(frame, bool):
            raise ValueError(f"frames.csv: 'frame' must be an integer, got {frame!r}")
        selection_rows = list(selection_rows)
        for row in selection_rows:
            if row.get("frame") != frame:
                raise ValueError(f"selection row of frame {row.get('frame')!r} given with frame {frame}")
            reason = row.get("reason") or ""
            if bool(row.get("selected")) and reason:
                raise ValueError(f"element {row.get('element')!r} is selected but has reason {reason!r}")
            if not bool(row.get("selected")) and reason not in REASONS:
                raise ValueError(f"element {row.get('element')!r} not selected: reason must be one "
                                 f"of {REASONS}, got {reason!r}")
        self._frames.check([frame_row])
        self._selection.check(selection_rows)
        self._selection.write(selection_rows)
        self._selection.flush()
        self._frames.write([frame_row])
        self._frames.flush()
        self._frame_values.append(tuple(frame_row.get(key) for key in FRAME_COLUMNS + ("setup_ms",)))
        for row in selection_rows:
            element = str(row["element"])
            states = self._selection_states.get(element)
            if states is None:
                states = self._selection_states[element] = (array("q"), bytearray())
            states[0].append(int(frame))
            states[1].append(1 if row["selected"] else 0)
        if self._facts is not None and (self._summary_written_at is None
                                        or self._clock() - self._summary_written_at >= self._summary_every_s):
            self.write_partial_summary()

    def write_partial_summary(self, extra=None):
        """Rewrite ``summary.json`` with ``"partial": true`` and the frames logged so far (an
        ``OSError`` of a full disk is raised; the previous summary then stays)."""
        if self._facts is None:
            raise ValueError("RunLog was opened without facts: it has no partial summary to write")
        self._write_summary({**self._facts, **(extra or {}), "partial": True})

    @staticmethod
    def _check_facts(facts):
        missing = [key for key in SUMMARY_REQUIRED_KEYS if key not in facts]
        if missing:
            raise ValueError(f"summary.json needs {missing} from the caller")

    def close(self, summary_extra):
        """Close both CSVs and write ``summary.json``; returns the summary dict.

        ``summary_extra`` must hold :data:`SUMMARY_REQUIRED_KEYS`; ``mode`` and
        ``budget_ms`` default to the frames' values.  Anything else it holds
        (``images``, ``cancelled``, ...) is copied into the summary.
        """
        if self._closed:
            raise ValueError("RunLog is already closed")
        summary_extra = {"partial": False, **(self._facts or {}), **summary_extra}
        self._check_facts(summary_extra)
        try:
            self._close_files()
        except OSError:
            pass  # a CSV could not take its last bytes (a full disk, reported by the writer): its complete rows stay
        return self._write_summary(summary_extra)

    def _write_summary(self, summary_extra):
        frame_rows = [dict(zip(FRAME_COLUMNS + ("setup_ms",), values)) for values in self._frame_values]
        selection_states = [{"frame": frame, "element": element, "selected": bool(selected)}
                            for element, (frames, flags) in self._selection_states.items()
                            for frame, selected in zip(frames, flags)]
        first = frame_rows[0] if frame_rows else {}
        summary = {"scene": summary_extra["scene"], "path": summary_extra["path"],
                   "mode": first.get("mode", summary_extra.get("mode")), "resolution": summary_extra["resolution"],
                   "budget_ms": first.get("budget_ms", summary_extra.get("budget_ms"))}
        summary.update(summarize(frame_rows, selection_states))
        summary["non_finite_values_dropped"] = sum(table.non_finite for table in (self._frames, self._selection)
                                                   if table is not None)
        summary["machine"] = machine_info()
        summary.update(summary_extra)
        summary = json_ready(summary)
        atomic.write_text(self.run_dir / SUMMARY_JSON, json.dumps(summary, indent=2, allow_nan=False) + "\n")
        self._summary_written_at = self._clock()
        self.summaries_written += 1
        return summary

    def _close_files(self):
        """Close both CSVs; the first write error (a full disk) is raised after both are closed."""
        self._closed = True
        errors = []
        for table in (self._selection, self._frames):
            try:
                table.close()
            except OSError as error:
                errors.append(error)
                table.abandon()
        if errors:
            raise errors[0]

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, traceback):
        """Leave the CSVs as they are (a cancelled run) if close() was not called."""
        if not self._closed:
            self._close_files()
        return False
