"""The Blender of this process: starting it quietly, registering PHRT, opening a scene.

Shared by the ``phrt`` command (``cli/__init__.py``), the sweep jobs (``cli/sweep.py``,
which run in this process or in a Dask worker) and the Dask worker set-up
(``cli/dask_worker.py``), so that none of them imports another's module for it.
Bad input raises :class:`UserError`: the ``phrt`` command prints it as one line
and exits with status 2.  ``bpy`` is imported inside the functions only.
"""
from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent  # the repository (the extension root), not cli/
SAMPLE_DIR = ROOT / "sample_scenes"


class UserError(Exception):
    """Bad input: printed as one line, exit status 2."""


@contextlib.contextmanager
def quiet_stdout():
    """Blender prints 'Saved: ...' per frame on stdout; keep stdout for our summary lines."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    try:
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(devnull)
        os.close(saved)


def import_blender():
    """Start Blender (import bpy) without its start-up log: Blender 5.x prints
    'color_management | Using OCIO=...' on stdout when the OCIO variable is set (5.2 sets
    it for its child processes).  Not on stderr either, where bad input gets one line."""
    if "bpy" not in sys.modules:
        with quiet_stdout():
            import bpy  # noqa: F401


def blender():
    """Import bpy and register the add-on from this package (idempotent)."""
    import bpy
    from .. import register
    if not hasattr(bpy.types.Scene, "phrt"):
        register()
    return bpy


def sample_is_stale(blend_path):
    """A sample .blend is rebuilt when missing, older than any of its generator's modules
    or saved by another Blender version."""
    if not blend_path.exists():
        return True
    built = blend_path.stat().st_mtime
    if any(module.stat().st_mtime > built for module in SAMPLE_DIR.glob("*.py")):
        return True
    import bpy
    from .. import compat
    return compat.blend_file_version(blend_path) != tuple(bpy.app.version[:2])


def scene_file(name_or_path) -> Path | None:
    """The .blend file ``load_scene(name_or_path)`` opens (a sample scene built first if missing or
    stale), None when there is none."""
    from ..sample_scenes import generate
    path = Path(name_or_path)
    if path.suffix.lower() != ".blend" and name_or_path in generate.SCENES:
        path = SAMPLE_DIR / f"{name_or_path}.blend"
        blender()
        if sample_is_stale(path):
            with quiet_stdout():
                generate.write_scene(name_or_path, SAMPLE_DIR)
        return path
    return path if path.is_file() else None


def _open(bpy, path):
    """Open a .blend with its scripts disabled whatever the user's preference (a file's registered
    text blocks and scripted drivers are code from whoever made it); warn once when it has some."""
    bpy.ops.wm.open_mainfile(filepath=str(path), use_scripts=False)
    texts = [text.name for text in bpy.data.texts if text.use_module]
    drivers = 0
    for collection in (bpy.data.objects, bpy.data.meshes, bpy.data.materials, bpy.data.scenes, bpy.data.lights,
                       bpy.data.cameras, bpy.data.worlds, bpy.data.node_groups, bpy.data.shape_keys):
        for datablock in collection:
            animation = getattr(datablock, "animation_data", None)
            for curve in (animation.drivers if animation is not None else ()):
                if curve.driver.type == "SCRIPTED" and not curve.driver.is_simple_expression:
                    drivers += 1
    if texts or drivers:
        parts = [f"text block{'s' if len(texts) > 1 else ''} {', '.join(repr(name) for name in texts)} "
                 f"(registered to run on load)"] if texts else []
        if drivers:
            parts.append(f"{drivers} scripted driver{'s' if drivers > 1 else ''}")
        print(f"phrt: warning: '{path.name}' holds scripts that were not run: {' and '.join(parts)} "
              f"(PHRT opens files with scripts disabled; the scene renders as if they were not there)",
              file=sys.stderr)


def load_scene(name_or_path):
    """Open a .blend file or a sample scene by name (built on first use); returns the scene's label."""
    from ..sample_scenes import generate
    path = Path(name_or_path)
    if path.suffix.lower() != ".blend" and name_or_path in generate.SCENES:
        path = SAMPLE_DIR / f"{name_or_path}.blend"
        bpy = blender()
        if sample_is_stale(path):
            with quiet_stdout():
                generate.write_scene(name_or_path, SAMPLE_DIR)
        with quiet_stdout():
            _open(bpy, path)
        return name_or_path
    if not path.exists():
        raise UserError(f"no such file or sample scene '{name_or_path}': give a .blend file or one of "
                        f"{', '.join(generate.SCENES)}")
    if path.is_dir() or path.suffix.lower() != ".blend":
        raise UserError(f"'{name_or_path}' is not a .blend file")
    with open(path, "rb") as handle:
        magic = handle.read(7)
    if magic not in (b"BLENDER",) and not magic.startswith(b"\x1f\x8b") and not magic.startswith(b"\x28\xb5\x2f\xfd"):
        raise UserError(f"'{name_or_path}' is not a valid .blend file (bad header)")
    bpy = blender()
    from .. import compat
    saved_by = compat.blend_file_version(path)
    if saved_by is not None and saved_by > tuple(bpy.app.version[:2]):
        print(f"phrt: warning: '{name_or_path}' was saved by Blender {saved_by[0]}.{saved_by[1]}, newer than this "
              f"Blender {bpy.app.version_string}: expect loss of data (save it from this version)", file=sys.stderr)
    try:
        with quiet_stdout():
            _open(bpy, path.resolve())
    except RuntimeError as error:
        raise UserError(f"cannot open '{name_or_path}': {str(error).strip().splitlines()[-1]}") from None
    return path.stem


def end_program(code: int):
    """End the ``phrt`` program with ``code`` once its output is flushed, without the C++
    static destructors of Blender's module: bpy 4.5's task scheduler waits forever in one
    (``GlobalState::~GlobalState``, in ``pthread_cond_destroy``) after a file's scripted
    driver was evaluated, and 4.5 and 5.0 print 'Not freed memory blocks' there.  Everything
    PHRT writes is closed before this (run folders are written atomically and unlocked)."""
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(int(code))


def quiet_exit():
    """Nothing Blender prints on stdout while the process ends reaches it: 4.5 and 5.0
    report 'Not freed memory blocks' there after opening a file saved by a newer Blender."""
    sys.stdout.flush()
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)
