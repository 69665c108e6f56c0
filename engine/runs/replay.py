"""Replaying a camera path: one RUN_DIR per mode (docs/formats.md).

Shared by the ``phrt.replay_path`` operator, the ``phrt`` command and the demo,
so the same input gives the same files whichever way a designer starts it.

A camera path is an animated camera object; its frame range is its
animation's (keyframes, or the scene range for a Follow Path constraint).
Frames are rendered one ``render.render()`` call at a time, with the state a
replay carries (Embree scenes uploaded once, cost model, last selection) held
by a ``ReplayState``; after each frame the image is written and the logs are
flushed, so a cancelled replay leaves complete frames and logs only.

A run folder has one writer (``.phrt-lock``, ``runs/lock.py``): a second replay into a live
run's folder is refused, a dead writer's lock taken over.  A folder holding another run is
reused only with ``overwrite=True`` (``--overwrite``), which removes that run's files first
(``runs/folder.py``).

Nothing half-written ever carries a final name: an image is written as
``frames/.NNNN.partial-HOST-PID.<ext>``, checked to be complete (``run_files.image_is_complete``:
a full disk makes Blender's writers stop early without an error) and renamed;
``summary.json`` exists from the start (``"partial": true``), is rewritten as frames complete
and is the run's commit record (``phrt_addon/runs/run_log.py``).  Cancelled (Esc,
``should_stop``), interrupted (SIGINT, SIGTERM: the frame being rendered is
finished first) or failed (a full disk) runs still get a ``summary.json`` with
``"partial": true`` (and ``"error"`` when they failed), if the disk takes it.
A problem of the scene (an object skipped...) is warned about once per replay
and listed with its count in ``summary.json`` (``problems``).
"""
from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import bpy

from ... import compat
from ...phrt_addon.raster import gbuffer
from ...phrt_addon.runs import run_log
from ...phrt_addon import schema
from ...phrt_addon.runs import folder as run_folder
from ...phrt_addon.runs import lock, run_files, work
from ...phrt_addon.schema import COPIED_FRAME_COLUMNS, EXTRA_FRAME_COLUMNS, REPLAY_ORDER
from .. import extract, final
from .camera_path import ReplayError, check_frame_range
from .interrupts import captured_stderr, stop_on_signals

# Hybrid last: with a budget between the modes (Budget At), a replay of several modes resolves it
# from the raster and raytrace runs it has just written beside the hybrid one (no calibration).
MODES = REPLAY_ORDER  # the order a replay of several modes runs them in
IMAGE_FORMATS = ("exr", "png", "none")


def _set_image_format(scene, images):
    settings = scene.render.image_settings
    if images == "exr":
        compat.set_image_format(settings, compat.MULTILAYER_EXR)
        settings.exr_codec = "ZIP"
        settings.color_depth = "32"
    elif images == "png":
        compat.set_image_format(settings, compat.PNG)
        settings.color_mode = "RGBA"
        settings.color_depth = "8"


def versions() -> dict:
    try:
        from importlib.metadata import version
        embreex_version = version("embreex")
    except Exception:  # the extension's bundled wheel may have no metadata
        embreex_version = "unknown"
    return {"blender_version": bpy.app.version_string, "embreex_version": embreex_version}


@dataclasses.dataclass
class ReplayResult:
    run_dir: Path
    mode: str
    frames_done: int
    cancelled: bool
    summary: dict | None
    signal: str | None = None  # "SIGINT" / "SIGTERM" when a signal stopped the replay
    problems: list = dataclasses.field(default_factory=list)  # one line per distinct problem, with its count


def check_input(*, mode=None, images=None, budget_ms=None, budget_at=None, frame_range=None):
    """ReplayError unless the replay arguments given are valid: the one check of them, made by
    ``ReplayRun`` and, before anything is loaded or written, by the ``phrt`` command (whose option
    names the messages use: the parameters are named alike)."""
    if mode is not None and str(mode).upper() not in MODES:
        raise ReplayError(f"unknown mode '{mode}': use raster, hybrid or raytrace")
    if images is not None and images not in IMAGE_FORMATS:
        raise ReplayError(f"unknown image format '{images}': use exr, png or none")
    if budget_ms is not None and not budget_ms >= 0:
        raise ReplayError(f"budget {budget_ms:g} ms is not >= 0: give --budget-ms a frame time >= 0")
    if budget_at is not None and not 0.0 <= budget_at <= 1.0:
        raise ReplayError(f"--budget-at {budget_at:g} is outside 0..1: give the fraction of the way from raster (0) "
                          f"to ray traced (1) frame time, e.g. --budget-at 0.33")
    if frame_range is not None:
        check_frame_range(*frame_range)


class ReplayInterrupted(ReplayError):
    """The frame's render was stopped (Esc during a render): nothing of it was kept."""


class ReplayRun:
    """One replay of a camera path into one RUN_DIR, rendered a frame per ``step()`` (the modal
    operator steps it from a timer; ``replay()`` loops over it).

    ``run = ReplayRun(...)``; ``while run.remaining: run.step()``;
    ``run.finish(cancelled=...)`` writes ``summary.json`` and restores the scene.
    An exception in ``step()`` restores the scene and leaves the complete rows
    written so far (like ``replay()``); ``ReplayInterrupted`` (the render itself was
    stopped) leaves the run open for ``finish(cancelled=True)``.  ``restores_scene=False``: neither
    does (several runs open on one scene at once restore it once, ``restore_scene()``); ``facts``:
    more entries of ``summary.json``."""

    def __init__(self, scene, camera, frame_range, mode, run_dir, *, images="exr", budget_ms=None,
                 resolution=None, scene_label=None, budget_at=None, budget_search_dirs=None,
                 overrides=None, frame_list=None, overwrite=False, restores_scene=True, facts=None):
        check_input(mode=mode, images=images, budget_ms=budget_ms, budget_at=budget_at, frame_range=frame_range)
        mode = mode.upper()
        self.restores_scene = bool(restores_scene)
        start, end = frame_range
        requested_budget_ms = budget_ms
        settings = extract.read_settings(scene)
        for key, value in (overrides or {}).items():
            if not hasattr(settings, key):
                raise ReplayError(f"unknown setting '{key}'")
            setattr(settings, key, value)
        # A budget between the modes is resolved to milliseconds once, before the first frame.
        fraction = budget_at if budget_at is not None else settings.budget_at
        settings.budget_at = None
        budget_source = None
        if budget_ms is None and fraction is not None and mode == "HYBRID":
            from . import calibration as budget_module
            resolved = budget_module.resolve(
                scene, camera, frame_range, fraction, runner=ReplayRun, resolution=resolution,
                scene_label=scene_label,
                search_dirs=[Path(run_dir).parent] if budget_search_dirs is None else budget_search_dirs)
            budget_ms = resolved.budget_ms
            budget_source = resolved.as_summary()
        self.run_dir = Path(run_dir)
        self.frames_dir = self.run_dir / schema.FRAMES_DIR
        width, height = resolution if resolution is not None else extract.resolution(scene)
        problem = gbuffer.resolution_problem(width, height)
        if problem is not None:
            raise ReplayError(problem)
        try:
            self._lock = run_folder.take(self.run_dir, overwrite)
        except run_folder.FolderError as error:
            raise ReplayError(str(error)) from None
        self._work = work.work_record(bpy.data.filepath or None, (start, end), (width, height), mode=mode,
                                      images=images, budget_ms=requested_budget_ms,
                                      budget_at=fraction if mode == "HYBRID" else None,
                                      overrides=overrides)
        self.scene, self.mode, self.images = scene, mode, images
        # A range is lazy: --frames 1-2000000000 holds no list of two billion frames.
        self.frames = range(start, end + 1) if frame_list is None else [int(f) for f in frame_list]
        self.done = 0
        self.settings = settings
        self.settings.mode = mode
        # A budget given here holds for the whole replay; otherwise the scene's (possibly
        # animated) budget is read at every frame.
        self._budget_fixed = budget_ms is not None or "budget_ms" in (overrides or {})
        if budget_ms is not None:
            self.settings.budget_ms = float(budget_ms)
        render = scene.render
        self._saved = {"camera": scene.camera, "frame": scene.frame_current, "filepath": render.filepath,
                       "res": (render.resolution_x, render.resolution_y, render.resolution_percentage),
                       "engine": render.engine, "use_ext": render.use_file_extension}
        self._image_saved = compat.image_format_state(render.image_settings)
        scene.camera = camera
        render.engine = "PHRT"
        if resolution is not None:
            render.resolution_x, render.resolution_y = resolution
            render.resolution_percentage = 100
        _set_image_format(scene, images)
        render.use_file_extension = True
        # Everything summary.json needs, read now: finish() may run when the scene is gone.
        self._summary = {
            "scene": scene_label or scene.name, "path": camera.name, "resolution": [width, height],
            "images": images, "frame_range": [start, end], "cost_mode": self.settings.cost_mode,
            "selection_weight": self.settings.selection_weight,
            "max_area_fraction": self.settings.max_area_fraction,
            "relevance": str(self.settings.relevance).lower(),
            "selection_order": str(self.settings.selection_order).lower(),
            "selection": str(self.settings.selection).lower(),
            "quality_tiers": bool(getattr(self.settings, "quality_tiers", False)),
            "budget_at": fraction if mode == "HYBRID" and budget_source is not None else None,
            "budget_source": budget_source, "work": self._work, **versions(), **(facts or {})}
        try:
            self.log = run_log.RunLog(self.run_dir, extra_frame_columns=EXTRA_FRAME_COLUMNS,
                                     facts={**self._summary, "mode": mode, "budget_ms": self.settings.budget_ms,
                                            "frames_planned": self.total, "cancelled": False})
        except OSError as error:
            self._lock.release()
            self._restore()
            raise ReplayError(f"cannot write the run in '{self.run_dir}': {error.strerror or error} "
                              f"(is the disk full?)") from None
        except BaseException:
            self._lock.release()
            self._restore()
            raise
        self.state = final.ReplayState(settings_override=self.settings, camera=camera).__enter__()
        self._open = True

    @property
    def total(self) -> int:
        return len(self.frames)

    @property
    def remaining(self) -> int:
        return self.total - self.done

    def step(self) -> dict:
        """Render, write and log the next frame; returns its stats."""
        if not self._open or not self.remaining:
            raise ValueError("ReplayRun: no frame left to render")
        frame = self.frames[self.done]
        scene, render, state = self.scene, self.scene.render, self.state
        try:
            scene.frame_set(frame)
            if not self._budget_fixed:
                self.settings.budget_ms = _scene_budget_ms(scene, self.settings.budget_ms)
            # Written under a temporary name, renamed once complete (see _commit_image).
            render.filepath = str(self._partial_image(frame))
            begin = time.perf_counter()
            with captured_stderr() as blender_said:
                bpy.ops.render.render(write_still=self.images != "none")
            wall_ms = (time.perf_counter() - begin) * 1000.0
            result = state.last_result
            if result is None:  # a failed render raises RuntimeError: this one was stopped
                self._drop_partial_images(frame)
                raise ReplayInterrupted(f"frame {frame} was stopped while rendering")
            if self.images != "none":
                self._commit_image(frame, blender_said)
            blender_said.forward()
            row = {key: result.stats.get(key) for key in schema.FRAME_COLUMNS}
            row.update({key: result.stats.get(COPIED_FRAME_COLUMNS.get(key, key)) for key in EXTRA_FRAME_COLUMNS})
            row["wall_ms"] = wall_ms
            self.log.add_frame(row, result.selection_rows)
            state.last_result = None
        except ReplayInterrupted:
            raise
        except OSError as error:  # a full disk or a file-size limit while writing the logs
            error = ReplayError(f"cannot write the run in '{self.run_dir}': {error.strerror or error} "
                                f"(is the disk full?); the {self.done} frames before frame {frame} are complete")
            self._fail(error)
            raise error from None
        except BaseException as error:
            self._fail(error)
            raise
        self.done += 1
        return result.stats

    def _partial_image(self, frame) -> Path:
        return self.frames_dir / f".{frame:04d}.partial-{lock.owner_tag()}"

    def _drop_partial_images(self, frame):
        for image in self.frames_dir.glob(f".{frame:04d}.partial-{lock.owner_tag()}*"):
            image.unlink(missing_ok=True)

    def _commit_image(self, frame, blender_said=None):
        """Give the frame's image its name once it is complete; a writer that hit a full disk
        leaves a file that ends early, with no error from Blender (or only a line on stderr, on
        4.5): it is removed and reported in one line."""
        extension = ".exr" if self.images == "exr" else ".png"
        partial = self.frames_dir / f"{self._partial_image(frame).name}{extension}"
        if not run_files.image_is_complete(partial):
            self._drop_partial_images(frame)
            reason = blender_said.reason() if blender_said is not None else ""
            raise ReplayError(f"frame {frame} could not be written completely to '{self.frames_dir}' (is the disk "
                              f"full, or a file-size limit reached?{' Blender: ' + reason if reason else ''}); "
                              f"the {self.done} frames before it are complete")
        os.replace(partial, self.frames_dir / f"{frame:04d}{extension}")

    def _fail(self, error):
        """Close the run after an error: complete frames and rows stay, ``summary.json`` says
        the run is partial (if the disk still takes it)."""
        if not self._open:
            return
        self._drop_partial_images(self.frames[min(self.done, len(self.frames) - 1)])
        summary = {**self._run_facts(), "cancelled": False, "partial": True,
                   "error": str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__}
        try:
            self._close(summary=summary, restore_scene=self.restores_scene)
        except OSError:
            self._open = False

    def restore_scene(self):
        """Put back the scene settings this run found (camera, frame, output, resolution, engine)."""
        self._restore()

    def finish(self, cancelled=False, restore_scene=True) -> ReplayResult:
        """Write ``summary.json`` (``cancelled`` says whether frames were left out) and restore
        the scene (``restore_scene=False`` when Blender is discarding it)."""
        if not self._open:
            raise ValueError("ReplayRun: already finished")
        cancelled = bool(cancelled and self.remaining)
        problems = self.problem_lines()
        try:
            written = self._close(summary={**self._run_facts(), "cancelled": cancelled,
                                           "partial": bool(self.remaining)},
                                  restore_scene=restore_scene and self.restores_scene)
        except OSError as error:  # the last summary.json did not fit: the one before stays, partial
            raise ReplayError(f"cannot write the run's summary in '{self.run_dir}': {error.strerror or error} "
                              f"(is the disk full?); its {self.done} frames are complete, the summary "
                              f"written before says fewer") from None
        return ReplayResult(run_dir=self.run_dir, mode=self.mode, frames_done=self.done,
                            cancelled=cancelled, summary=written, problems=problems)

    def problem_lines(self) -> list:
        """Each problem of the run once, with the number of frames it came up on."""
        return self.state.renderer.problems.lines(self.done)

    def _run_facts(self) -> dict:
        return {**self._summary, "frames_planned": self.total,
                "problems": self.state.renderer.problems.summary()}

    def _close(self, summary, restore_scene=True):
        if not self._open:
            return None
        self._open = False
        written = None
        try:
            written = self.log.close(summary)
        finally:
            self._lock.release()
            self.state.__exit__(None, None, None)
            if restore_scene:
                self._restore()
        return written

    def _restore(self):
        scene, render, saved = self.scene, self.scene.render, self._saved
        scene.camera = saved["camera"]
        scene.frame_set(saved["frame"])
        render.filepath = saved["filepath"]
        render.resolution_x, render.resolution_y, render.resolution_percentage = saved["res"]
        render.engine = saved["engine"]
        render.use_file_extension = saved["use_ext"]
        compat.restore_image_format(render.image_settings, self._image_saved)


def _scene_budget_ms(scene, default):
    """The scene's frame budget at its current frame (it may be animated), or ``default``."""
    props = getattr(scene, "phrt", None)
    try:
        value = float(props.budget_ms)
    except (AttributeError, TypeError, ValueError):
        return default
    return value if value >= 0 else default


def replay(scene, camera, frame_range, mode, run_dir, *, images="exr", budget_ms=None, resolution=None,
           scene_label=None, on_progress=None, should_stop=None, budget_at=None, budget_search_dirs=None,
           overrides=None, overwrite=False) -> ReplayResult:
    """Render ``frame_range`` of ``camera`` in ``mode`` into ``run_dir``.

    ``on_progress(done, total, frame_ms)`` is called after each frame;
    ``should_stop()`` is polled between frames (Esc in the UI); SIGINT and SIGTERM stop the
    replay between frames too (``ReplayResult.signal``).  ``budget_at`` (or the scene's Budget
    At) is resolved to milliseconds from complete raster and raytrace runs of the path in
    ``budget_search_dirs`` (default: beside ``run_dir``) or by a short calibration, reported in
    ``summary.json`` (``budget_source``).  ``overrides`` sets fields of the scene's settings
    (``phrt_addon.scene.Settings``) for this replay only.  ``overwrite`` lets the replay replace
    another run in ``run_dir`` (its files are removed first); without it such a folder is refused."""
    run = ReplayRun(scene, camera, frame_range, mode, run_dir, images=images, budget_ms=budget_ms,
                        resolution=resolution, scene_label=scene_label, budget_at=budget_at,
                        budget_search_dirs=budget_search_dirs, overrides=overrides, overwrite=overwrite)
    cancelled = False
    received = []
    with stop_on_signals(received):
        while run.remaining:
            if received or (should_stop is not None and should_stop()):
                cancelled = True
                break
            try:
                stats = run.step()
            except ReplayInterrupted:
                cancelled = True  # stopped in the middle of a frame: that frame is not kept
                break
            if on_progress is not None:
                on_progress(run.done, run.total, stats["total_ms"])
        result = run.finish(cancelled=cancelled or bool(received))
    result.signal = received[0] if received else None
    return result


def default_run_dir(out_root, scene_label, camera_name, mode) -> Path:
    return Path(out_root) / f"{scene_label}-{camera_name}-{mode.lower()}"
