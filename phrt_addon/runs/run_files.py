"""The files of a RUN_DIR (docs/formats.md), read back: the logs as typed rows, the summary, the
images, whether an image file was written to its end.

The writer is ``run_log.RunLog``; ``summary.json`` is its commit record (it exists from the run's
start and is rewritten as frames complete): :func:`read_frames` reads the first
``frame_count`` rows of ``frames.csv``, :func:`read_selection` / :func:`iter_selection` the
selection rows of those frames, and :func:`run_images` the images of those frames in the format
the summary names (``"images"``: none, exr or png), nothing else.  So a run killed at any moment
reads back consistently, and images an earlier run left in the folder are never taken for this
run's.  A folder without ``summary.json`` (an older PHRT) reads ``frames.csv`` whole.  The CSVs
are parsed by the ``csv`` module over the whole file: a quoted cell may hold newlines or any
Unicode (U+2028, ``\\x85``, ``\\f``); an unfinished last record is ignored.  Plain Python, no ``bpy``.
"""
import array
import csv
import io
import json
import struct
from pathlib import Path

import numpy as np

from ..schema import BOOL_COLUMNS, FRAMES_CSV, FRAMES_DIR, SELECTION_CSV, STRING_COLUMNS, SUMMARY_JSON

IMAGE_SUFFIXES = {"exr": ".exr", "png": ".png"}


def _parse_cell(column, text):
    if column in STRING_COLUMNS:
        return text
    if text == "":
        return None
    if column in BOOL_COLUMNS:
        return text not in ("0", "False", "false")
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _records(handle):
    """CSV records of an open file (newline=""): the header, then each complete record.  A last
    record a writer stopped in the middle of (no line end, or inside a quoted cell) is left out;
    strict parsing also stops at a damaged record."""
    reader = csv.reader(handle, strict=True)
    previous = None
    try:
        for record in reader:
            if previous is not None:
                yield previous
            previous = record
    except csv.Error:  # the record being parsed is unfinished or damaged: the one before it is whole
        if previous is not None:
            yield previous
        return
    if previous is not None and _ends_with_newline(handle):
        yield previous


def _ends_with_newline(handle) -> bool:
    raw = handle.buffer
    raw.seek(0, io.SEEK_END)
    if raw.tell() == 0:
        return False
    raw.seek(-1, io.SEEK_END)
    return raw.read(1) == b"\n"


def _iter_csv(path, limit_frames=None):
    """Typed rows (dicts) of a CSV log, streamed; only rows whose frame is in ``limit_frames``."""
    try:
        handle = open(path, newline="", encoding="utf-8")
    except FileNotFoundError:
        return
    with handle:
        records = _records(handle)
        header = next(records, None)
        if header is None:
            return
        frame_at = header.index("frame") if "frame" in header else None
        for cells in records:
            if len(cells) != len(header):
                continue
            if limit_frames is not None and (frame_at is None or _parse_cell("frame", cells[frame_at])
                                             not in limit_frames):
                continue
            yield {column: _parse_cell(column, cell) for column, cell in zip(header, cells)}


def _summary_or_none(run_dir):
    try:
        return read_summary(run_dir)
    except (FileNotFoundError, ValueError):
        return None


def read_frames(run_dir, summary=None):
    """Rows of ``frames.csv`` as dicts of typed values (``None`` for empty cells): the first
    ``frame_count`` of them when the folder has a ``summary.json`` (the frames it commits)."""
    summary = _summary_or_none(run_dir) if summary is None else summary
    rows = list(_iter_csv(Path(run_dir) / FRAMES_CSV))
    if summary is not None and isinstance(summary.get("frame_count"), int):
        rows = rows[: summary["frame_count"]]
    return rows


def iter_selection(run_dir, summary=None):
    """Rows of ``selection.csv`` of the frames :func:`read_frames` reads, streamed (one dict at a
    time: a report never holds a whole selection log).  ``visible`` and ``selected`` are bools,
    ``element`` and ``reason`` strings."""
    frames = {row["frame"] for row in read_frames(run_dir, summary)}
    yield from _iter_csv(Path(run_dir) / SELECTION_CSV, limit_frames=frames)


def read_selection(run_dir, summary=None):
    """:func:`iter_selection` as a list."""
    return list(iter_selection(run_dir, summary))


class SelectionStates:
    """Each frame's (element, selected) pairs of a run in the order of ``selection.csv``, read in one
    streaming pass and kept compact (an index and a byte per row, not a dict): what the report's
    flips and popping need.  Iterating yields ``{"frame", "element", "selected"}`` dicts, with
    ``"effects"`` and ``"rate"`` where the log has them (``BENEFIT``: what of a traced element was
    traced, at which rate; popping counts a change of them as a pop), kept as an index into a
    table of the distinct pairs."""

    def __init__(self, run_dir, summary=None):
        self.names, index = [], {}
        self.traced_as, traced_index = [], {}  # distinct (effects, rate) pairs
        self.by_frame = {}  # frame -> (element indices, selected flags, (effects, rate) indices or -1)
        for row in iter_selection(run_dir, summary):
            name = str(row["element"])
            position = index.get(name)
            if position is None:
                position = index[name] = len(self.names)
                self.names.append(name)
            entry = self.by_frame.get(row["frame"])
            if entry is None:
                entry = self.by_frame[row["frame"]] = (array.array("i"), bytearray(), array.array("i"))
            entry[0].append(position)
            entry[1].append(1 if row["selected"] else 0)
            traced = (row.get("effects"), row.get("rate"))
            if traced == (None, None):
                entry[2].append(-1)
            else:
                at = traced_index.get(traced)
                if at is None:
                    at = traced_index[traced] = len(self.traced_as)
                    self.traced_as.append(traced)
                entry[2].append(at)
        self._flips = None

    def __iter__(self):
        for frame, (elements, flags, traced) in self.by_frame.items():
            for position, selected, at in zip(elements, flags, traced):
                row = {"frame": frame, "element": self.names[position], "selected": bool(selected)}
                if at >= 0:
                    row["effects"], row["rate"] = self.traced_as[at]
                yield row

    def __len__(self):
        return sum(len(flags) for _, flags in self.by_frame.values())

    def flips_per_element_per_100(self) -> dict:
        """``runs.summary.flips_per_element_per_100`` of these rows, computed once."""
        if self._flips is None:
            frames = sorted(self.by_frame)
            states = {}
            for frame in frames:
                elements, flags, _ = self.by_frame[frame]
                for position, selected in zip(elements, flags):
                    states.setdefault(position, bytearray()).append(selected)
            count = len(frames)
            self._flips = {} if count == 0 else {
                self.names[position]: 100.0 * int(np.count_nonzero(np.diff(np.frombuffer(bytes(flags), np.uint8))))
                / count for position, flags in states.items()}
        return self._flips


def read_summary(run_dir):
    """``summary.json`` as a dict; ``FileNotFoundError`` if the folder holds no run."""
    path = Path(run_dir) / SUMMARY_JSON
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: the folder holds no run")
    return json.loads(path.read_text(encoding="utf-8"))


def frame_image_path(run_dir, frame, images=None):
    """The image of ``frame`` in ``RUN_DIR/frames`` in the run's format (``images``: 'exr', 'png'
    or 'none'; by default the summary's), or None (no image, or the run writes none)."""
    if images is None:
        summary = _summary_or_none(run_dir)
        images = summary.get("images") if summary is not None else None
    suffixes = (IMAGE_SUFFIXES[images],) if images in IMAGE_SUFFIXES else () if images == "none" \
        else (".exr", ".png")
    for suffix in suffixes:
        path = Path(run_dir) / FRAMES_DIR / f"{int(frame):04d}{suffix}"
        if path.exists():
            return path
    return None


def run_images(run_dir, summary=None) -> dict:
    """{frame: image path} of the frames the run commits, in the format its summary names."""
    summary = _summary_or_none(run_dir) if summary is None else summary
    images = summary.get("images") if summary is not None else None
    found = {}
    for row in read_frames(run_dir, summary):
        path = frame_image_path(run_dir, row["frame"], images)
        if path is not None:
            found[row["frame"]] = path
    return found


EXR_MAGIC = b"\x76\x2f\x31\x01"
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
# Scanlines per chunk of each OpenEXR compression (single-part files carry no chunk count).
_EXR_LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}


def image_is_complete(path) -> bool:
    """Whether an image file was written to its end: a PNG ends with its IEND chunk; an
    OpenEXR file (scanline, single- or multi-part) has every chunk of its offset tables
    filled in and inside the file.  A writer that hit a full disk or a file-size limit
    can leave a file that starts well and ends early (Blender reports no error then)."""
    path = Path(path)
    try:
        size = path.stat().st_size
        with open(path, "rb") as handle:
            if path.suffix.lower() == ".png":
                if size < 8 + len(PNG_END):
                    return False
                handle.seek(size - len(PNG_END))
                return handle.read() == PNG_END
            if path.suffix.lower() == ".exr":
                return _exr_is_complete(handle, size)
    except (OSError, ValueError, struct.error):
        return False
    return size > 0


def _exr_is_complete(handle, size) -> bool:
    if handle.read(4) != EXR_MAGIC:
        return False
    flags = struct.unpack("<I", handle.read(4))[0]
    multipart, tiled = bool(flags & 0x1000), bool(flags & 0x200)
    if tiled:
        return size > 8  # not written by Blender's multilayer output; not checked further

    def read_string():
        data = bytearray()
        while True:
            byte = handle.read(1)
            if not byte:
                raise ValueError("truncated header")
            if byte == b"\0":
                return bytes(data)
            data += byte
            if len(data) > 1024:
                raise ValueError("header name too long")

    headers = []
    while True:
        attributes = {}
        name = read_string()
        if not name:
            break  # the empty header ending a multi-part header list
        while name:
            kind = read_string()
            length = struct.unpack("<i", handle.read(4))[0]
            if length < 0 or length > size:
                raise ValueError("bad attribute size")
            attributes[name] = (kind, handle.read(length))
            name = read_string()
        headers.append(attributes)
        if not multipart:
            break
    chunk_counts = []
    for attributes in headers:
        if b"chunkCount" in attributes:
            chunk_counts.append(struct.unpack("<i", attributes[b"chunkCount"][1])[0])
            continue
        y_min, y_max = struct.unpack("<4i", attributes[b"dataWindow"][1])[1::2]
        compression = attributes[b"compression"][1][0]
        lines = _EXR_LINES_PER_CHUNK.get(compression, 1)
        chunk_counts.append(-(-(y_max - y_min + 1) // lines))
    leader = 12 if multipart else 8  # (part,) y, packed size
    for count in chunk_counts:
        if count <= 0:
            return False
        offsets = struct.unpack(f"<{count}Q", handle.read(8 * count))
        if min(offsets) == 0 or max(offsets) + leader > size:
            return False
        last = max(offsets)
        position = handle.tell()
        handle.seek(last + leader - 4)
        packed = struct.unpack("<i", handle.read(4))[0]
        if packed < 0 or last + leader + packed > size:
            return False
        handle.seek(position)
    return True
