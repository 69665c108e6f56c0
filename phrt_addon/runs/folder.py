"""Whether a folder can take a run (``output_dir_problem``: checked before anything is written, creating
nothing), and a run folder taken for one replay: created with its ``frames/``, locked (``lock.py``), refused
when it holds another run unless
the caller says to overwrite it, and then emptied of that run's files (after a ``summary.json``
that commits no frame has replaced the old one, so the folder never passes for the old run while
it is being emptied; nothing but a run's own files is removed) and of what dead writers left (temporary files of this host's dead processes).

Plain Python, no ``bpy``.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from ..schema import FRAMES_CSV, FRAMES_DIR, SELECTION_CSV, SUMMARY_JSON
from . import atomic, lock


class FolderError(ValueError):
    """The folder cannot take the run: the message (one line) says why and what to do."""


# The files of a run in its folder (docs/formats.md); --overwrite removes these and nothing else.
RUN_FILES = (SUMMARY_JSON, FRAMES_CSV, SELECTION_CSV)
RUN_IMAGES = ("[0-9]*.exr", "[0-9]*.png")


def _cannot_write(path, why) -> str:
    return f"cannot write to output folder '{path}': {why}"


def output_dir_problem(path):
    """Why the folder ``path`` cannot be created and written, or None if it can.
    Creates nothing: bad input is refused before anything is written."""
    path = Path(path).resolve()
    existing = path
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        return _cannot_write(path, f"'{existing}' is a file, not a folder")
    if not os.access(existing, os.W_OK | os.X_OK):
        return _cannot_write(path, f"permission denied on '{existing}'")
    return None


def holds_run(run_dir: Path) -> str | None:
    """A one-line description of the run in ``run_dir``, or None when it holds none."""
    summary = run_dir / SUMMARY_JSON
    if summary.exists():
        try:
            facts = json.loads((run_dir / SUMMARY_JSON).read_text(encoding="utf-8"))
            what = (f"{facts.get('scene')}/{facts.get('path')} {str(facts.get('mode') or '').lower()}, "
                    f"{facts.get('frame_count')} frames{', partial' if facts.get('partial') else ''}")
        except (OSError, ValueError):
            what = "an unreadable summary.json"
        return what
    frames = run_dir / FRAMES_DIR
    if any((run_dir / name).exists() for name in RUN_FILES[1:]) or (
            frames.is_dir() and any(next(frames.glob(pattern), None) for pattern in RUN_IMAGES)):
        return "logs or images of a run"
    return None


def take(run_dir: Path, overwrite: bool):
    """Lock ``run_dir`` for this replay; refuse it (FolderError) when another live writer holds it,
    or when it holds another run and ``overwrite`` is not given; with ``overwrite``, remove that
    run's files (summary.json first) and what dead writers left.  ``run_dir/frames`` exists after."""
    try:
        taken = lock.acquire(run_dir)
    except lock.LockHeld as error:
        raise FolderError(str(error)) from None
    except OSError as error:
        raise FolderError(_cannot_write(run_dir, error.strerror or error)) from None
    try:
        held = holds_run(run_dir)
        if held is not None and not overwrite:
            raise FolderError(f"'{run_dir}' holds another run ({held}): give --overwrite to replace it, or "
                              f"another --out")
        frames = run_dir / FRAMES_DIR
        if held is not None:
            # First a summary that commits nothing: killed at any moment of the clean-up, the folder
            # reads back as a run of 0 frames, never as the old run with some of its files gone.
            atomic.write_text(run_dir / SUMMARY_JSON, json.dumps(
                {"partial": True, "frame_count": 0, "images": "none", "replacing": held}) + "\n")
            for name in RUN_FILES[1:]:
                (run_dir / name).unlink(missing_ok=True)
            for pattern in RUN_IMAGES:
                for image in frames.glob(pattern) if frames.is_dir() else ():
                    image.unlink(missing_ok=True)
        for folder in (run_dir, frames):
            for leftover in atomic.dead_temporaries(folder):
                leftover.unlink(missing_ok=True)
        for leftover in frames.glob(".*.partial-*") if frames.is_dir() else ():
            if lock.tag_is_dead(leftover.name.split(".partial-", 1)[1].split(".", 1)[0]):
                leftover.unlink(missing_ok=True)
        frames.mkdir(exist_ok=True)
    except OSError as error:
        taken.release()
        raise FolderError(_cannot_write(run_dir, error.strerror or error)) from None
    except BaseException:
        taken.release()
        raise
    return taken
