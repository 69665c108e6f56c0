"""Files that appear whole or not at all: written under a temporary name that carries the
writer's host and pid (``NAME.tmp-HOST-PID``, see ``lock.owner_tag``), then renamed.

A reader never sees a half-written file under its final name, two writers never share a
temporary name, and a clean-up can tell a dead writer's leftovers (``lock.tag_is_dead``) from a
live one's.  A failed write (a full disk) removes its temporary file and raises the
``OSError``.  Plain Python, no ``bpy``.
"""
from __future__ import annotations

import contextlib
import os
from pathlib import Path

from .lock import owner_tag, tag_is_dead

TEMPORARY_MARK = ".tmp-"


def temporary_path(path) -> Path:
    path = Path(path)
    return path.with_name(f"{path.name}{TEMPORARY_MARK}{owner_tag()}")


@contextlib.contextmanager
def atomic_open(path, mode="w", **kwargs):
    """``open`` on a temporary name; renamed to ``path`` when the block ends without an error,
    removed otherwise.  ``mode`` is "w" (text, utf-8 by default) or "wb"."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes new files only ('w' or 'wb'), not {mode!r}")
    if mode == "w":
        kwargs.setdefault("encoding", "utf-8")
    path = Path(path)
    temporary = temporary_path(path)
    try:
        with open(temporary, mode, **kwargs) as handle:
            yield handle
        os.replace(temporary, path)
    except BaseException:
        with contextlib.suppress(OSError):
            temporary.unlink()
        raise


def write_text(path, text: str) -> Path:
    with atomic_open(path, "w") as handle:
        handle.write(text)
    return Path(path)


def write_bytes(path, data: bytes) -> Path:
    with atomic_open(path, "wb") as handle:
        handle.write(data)
    return Path(path)


def save_figure(figure, path, **kwargs) -> Path:
    """A matplotlib figure saved as PNG through a temporary name."""
    with atomic_open(path, "wb") as handle:
        figure.savefig(handle, format="png", **kwargs)
    return Path(path)


def dead_temporaries(folder) -> list:
    """Temporary files in ``folder`` left by writers that are gone (this host, no such process)."""
    found = []
    for path in Path(folder).iterdir() if Path(folder).is_dir() else ():
        name = path.name
        if TEMPORARY_MARK in name and tag_is_dead(name.rpartition(TEMPORARY_MARK)[2]):
            found.append(path)
    return found
