"""The files of a RUN_DIR (docs/formats.md), read back: the logs as typed rows, the summary, the
images, whether an image file was written to its end; and whether a folder can hold a run.

The writer is ``runlog.RunLog``; ``frames.csv`` is its commit record, so
:func:`read_selection` ignores selection rows of frames absent from ``frames.csv``
(a replay killed half way through writing a frame), and an unfinished last CSV line
is ignored.  Plain Python, no ``bpy``.
"""
import csv
import json
import struct
import os
from pathlib import Path

from ..schema import BOOL_COLUMNS, FRAMES_CSV, FRAMES_DIR, SELECTION_CSV, STRING_COLUMNS, SUMMARY_JSON


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


def _read_csv(path):
    """Rows of a CSV log as dicts; an unfinished last line is ignored."""
    text = Path(path).read_text(encoding="utf-8")
    if text and not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    reader = csv.reader(text.splitlines())
    header = next(reader, None)
    if header is None:
        return []
    return [{column: _parse_cell(column, cell) for column, cell in zip(header, cells)}
            for cells in reader if len(cells) == len(header)]


def read_frames(run_dir):
    """Rows of ``frames.csv`` as dicts of typed values (``None`` for empty cells)."""
    return _read_csv(Path(run_dir) / FRAMES_CSV)


def read_selection(run_dir):
    """Rows of ``selection.csv`` of the frames that ``frames.csv`` records.

    ``visible`` and ``selected`` are bools, ``element`` and ``reason`` strings.
    """
    frames = {row["frame"] for row in read_frames(run_dir)}
    return [row for row in _read_csv(Path(run_dir) / SELECTION_CSV) if row["frame"] in frames]


def read_summary(run_dir):
    """``summary.json`` as a dict; ``FileNotFoundError`` if the run never closed."""
    path = Path(run_dir) / SUMMARY_JSON
    if not path.exists():
        raise FileNotFoundError(f"{path} is missing: the run did not finish (RunLog.close)")
    return json.loads(path.read_text(encoding="utf-8"))


def frame_image_path(run_dir, frame):
    """The image of ``frame`` in ``RUN_DIR/frames`` (.exr preferred over .png), or None."""
    for suffix in (".exr", ".png"):
        path = Path(run_dir) / FRAMES_DIR / f"{int(frame):04d}{suffix}"
        if path.exists():
            return path
    return None


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


def output_dir_problem(path):
    """Why the folder ``path`` cannot be created and written, or None if it can.
    Creates nothing: bad input is refused before anything is written."""
    path = Path(path).resolve()
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        return f"cannot write to output folder '{path}': '{existing}' is a file, not a folder"
    if not os.access(existing, os.W_OK | os.X_OK):
        return f"cannot write to output folder '{path}': permission denied on '{existing}'"
    return None
