"""``phrt.replay_path``: replay a camera path over a frame range in one or more modes,
one RUN_DIR per mode (docs/properties.md, docs/formats.md).

Two ways to run, same files:

- In the UI (invoked from the N panel, F3, a button): a modal operator renders one
  frame per timer tick, shows progress (cursor counter and status bar) and stops
  between frames on Esc.  What was rendered stays valid: complete frames, flushed
  logs and a ``summary.json`` marked ``"cancelled": true`` and ``"partial": true``.
- From a script or ``blender -b`` (``bpy.ops.phrt.replay_path(...)``, i.e. execute):
  ``engine.runs.replay.replay()`` runs every frame of every mode to the end.

The modal path drives ``engine.runs.replay.ReplayRun`` (of which ``replay()`` is the
blocking loop), so both write exactly the same files.
docs/batch.md has the ``blender -b`` command lines.
"""

from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty

from ..engine import candidate_list
from ..engine.runs import replay
from ..engine.runs import camera_path
from ..properties import BLEND_RELATIVE_PATH, IMAGE_ITEMS, MODE_FLAG_ITEMS
from ..phrt_addon.runs import folder as run_folder

# Events a running replay lets through, so the designer can still look around.
_NAVIGATION_EVENTS = {"MIDDLEMOUSE", "WHEELUPMOUSE", "WHEELDOWNMOUSE", "TRACKPADPAN", "TRACKPADZOOM",
                      "MOUSEMOVE", "INBETWEEN_MOUSEMOVE", "NDOF_MOTION"}


def scene_label(scene) -> str:
    """How run folders name the scene: the .blend file's name (as ``phrt render`` does), else the scene's."""
    return Path(bpy.data.filepath).stem if bpy.data.filepath else scene.name


def output_root(output_dir: str) -> Path:
    """``output_dir`` as an absolute folder ('//' is the .blend file's folder, or the
    working directory of an unsaved file)."""
    return Path(bpy.path.abspath(output_dir or "//phrt_runs")).resolve()


def check_output_root(root: Path):
    """ReplayError unless the folder ``root`` can be created and written (creates nothing)."""
    problem = run_folder.output_dir_problem(root)
    if problem is not None:
        raise camera_path.ReplayError(problem)


def _path_search(self, context, edit_text):
    return [camera.name for camera in camera_path.camera_paths(context.scene) if edit_text.lower() in camera.name.lower()]


def _refresh_candidates(context):
    """Update the N panel's candidate list from the last frame (if the panels are registered)."""
    candidate_list.refresh(context.window_manager, context.scene)


class PHRT_OT_replay_path(bpy.types.Operator):
    """Render a camera path frame by frame in the chosen modes, writing one run folder per mode
    (frames, frames.csv, selection.csv, summary.json). Esc stops between frames"""

    bl_idname = "phrt.replay_path"
    bl_label = "Replay Camera Path"
    bl_options = {"REGISTER"}

    path: StringProperty(
        name="Camera Path", search=_path_search,
        description="The animated camera to replay; empty: the scene's first path "
                    "(its 'phrt_paths' order, else the active camera)",
    )
    frame_start: IntProperty(
        name="Start Frame", min=0,
        description="First frame to render (default: the path's first keyframe)",
    )
    frame_end: IntProperty(
        name="End Frame", min=0,
        description="Last frame to render (default: the path's last keyframe)",
    )
    modes: EnumProperty(
        name="Modes", items=MODE_FLAG_ITEMS, options={"ENUM_FLAG"}, default={"HYBRID"},
        description="Render the path once in each chosen mode, each into its own run folder",
    )
    output_dir: StringProperty(
        name="Output Folder", subtype="DIR_PATH", default="//phrt_runs", options=BLEND_RELATIVE_PATH,
        description="Run folders <scene>-<path>-<mode> are written here ('//' is the .blend file's folder)",
    )
    images: EnumProperty(
        name="Images", items=IMAGE_ITEMS, default="EXR",
        description="Image format of the rendered frames",
    )
    overwrite: BoolProperty(
        name="Overwrite", default=True,
        description="Replace the run a run folder already holds (its files are removed first); off, such a "
                    "folder is refused.  A folder another replay is writing is always refused",
    )

    # -- planning ---------------------------------------------------------------
    def _resolve(self, context):
        """(camera, (start, end), modes in order, output root); ReplayError on bad input."""
        scene = context.scene
        camera = camera_path.find_path(scene, self.path or None)
        start, end = camera_path.path_frame_range(scene, camera)
        if self.properties.is_property_set("frame_start"):
            start = self.frame_start
        if self.properties.is_property_set("frame_end"):
            end = self.frame_end
        camera_path.check_frame_range(start, end)
        modes = [mode for mode in replay.MODES if mode in self.modes]
        if not modes:
            raise camera_path.ReplayError("no mode chosen: pick at least one of raster, hybrid, raytrace")
        root = output_root(self.output_dir)
        check_output_root(root)
        return camera, (start, end), modes, root

    def _run_dir(self, context, camera, mode, root):
        return replay.default_run_dir(root, scene_label(context.scene), camera.name, mode)

    # -- blocking: scripts and background mode ------------------------------------
    def execute(self, context):
        try:
            camera, frame_range, modes, root = self._resolve(context)
        except camera_path.ReplayError as error:
            self.report({"ERROR"}, f"PHRT: {error}")
            return {"CANCELLED"}
        scene, window_manager = context.scene, context.window_manager
        frames = frame_range[1] - frame_range[0] + 1
        results = []
        window_manager.progress_begin(0, frames * len(modes))
        try:
            for index, mode in enumerate(modes):
                def progress(done, total, frame_ms, index=index, mode=mode):
                    window_manager.progress_update(index * frames + done)
                    if bpy.app.background:
                        print(f"PHRT replay {camera.name} {mode.lower()}: frame {done}/{total} "
                              f"({frame_ms:.0f} ms)", flush=True)
                results.append(replay.replay(
                    scene, camera, frame_range, mode, self._run_dir(context, camera, mode, root),
                    images=self.images.lower(), scene_label=scene_label(scene), on_progress=progress,
                    overwrite=self.overwrite))
                if results[-1].signal:  # SIGINT / SIGTERM (blender -b): no further mode
                    break
        except (camera_path.ReplayError, RuntimeError) as error:
            self.report({"ERROR"}, f"PHRT: replay of '{camera.name}' failed: {error}")
            return {"CANCELLED"}
        finally:
            window_manager.progress_end()
            _refresh_candidates(context)
        self._report_done(results, cancelled=False)
        return {"CANCELLED"} if any(result.signal for result in results) else {"FINISHED"}

    def _report_done(self, results, cancelled):
        runs = ", ".join(f"{result.mode.lower()} {result.frames_done} frames -> {result.run_dir}" for result in results)
        cancelled = cancelled or any(result.cancelled for result in results)
        verb = "cancelled" if cancelled else "done"
        # Each problem once per run, with its count (the frames warned only the first time).
        for line in dict.fromkeys(line for result in results for line in result.problems):
            self.report({"WARNING"}, f"PHRT: {line}")
        self.report({"WARNING" if cancelled else "INFO"}, f"PHRT replay {verb}: {runs or 'nothing rendered'}")

    # -- interactive: one frame per timer tick, Esc stops -----------------------------
    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            camera, frame_range, modes, root = self._resolve(context)
        except camera_path.ReplayError as error:
            self.report({"ERROR"}, f"PHRT: {error}")
            return {"CANCELLED"}
        self._camera, self._frame_range, self._modes, self._root = camera, frame_range, modes, root
        self._mode_index = 0
        self._run = None
        self._results = []
        self._frames_per_mode = frame_range[1] - frame_range[0] + 1
        window_manager = context.window_manager
        window_manager.progress_begin(0, self._frames_per_mode * len(modes))
        self._timer = window_manager.event_timer_add(0.01, window=context.window)
        window_manager.modal_handler_add(self)
        self._status(context, "starting")
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            return self._stop(context, cancelled=True)
        if event.type != "TIMER":
            return {"PASS_THROUGH"} if event.type in _NAVIGATION_EVENTS else {"RUNNING_MODAL"}
        try:
            if self._run is None:
                mode = self._modes[self._mode_index]
                self._run = replay.ReplayRun(context.scene, self._camera, self._frame_range, mode,
                                          self._run_dir(context, self._camera, mode, self._root),
                                          images=self.images.lower(), scene_label=scene_label(context.scene),
                                          overwrite=self.overwrite)
            stats = self._run.step()
            done = self._mode_index * self._frames_per_mode + self._run.done
            context.window_manager.progress_update(done)
            self._status(context, f"frame {self._run.done}/{self._run.total}, {stats['total_ms']:.0f} ms")
            if not self._run.remaining:
                self._results.append(self._run.finish())
                self._run = None
                self._mode_index += 1
                if self._mode_index == len(self._modes):
                    return self._stop(context, cancelled=False)
        except replay.ReplayInterrupted:  # Esc while a frame was rendering
            return self._stop(context, cancelled=True)
        except (camera_path.ReplayError, RuntimeError) as error:
            self._run = None  # step() already closed its logs and restored the scene
            self._cleanup(context)
            self.report({"ERROR"}, f"PHRT: replay of '{self._camera.name}' failed: {error}")
            return {"CANCELLED"}
        return {"RUNNING_MODAL"}

    def cancel(self, context):
        """Blender ends the operator itself (a file is loaded, the window closes): close the run
        so what was rendered stays valid, without touching a scene that may be gone."""
        if self._run is not None:
            self._run.finish(cancelled=True, restore_scene=False)
            self._run = None
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        context.window_manager.progress_end()

    def _stop(self, context, cancelled):
        if self._run is not None:
            self._results.append(self._run.finish(cancelled=cancelled))
            self._run = None
        self._cleanup(context)
        self._report_done(self._results, cancelled)
        return {"CANCELLED"} if cancelled else {"FINISHED"}

    def _cleanup(self, context):
        window_manager = context.window_manager
        if self._timer is not None:
            window_manager.event_timer_remove(self._timer)
            self._timer = None
        window_manager.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        _refresh_candidates(context)

    def _status(self, context, text):
        if context.workspace is None:
            return
        mode = self._modes[min(self._mode_index, len(self._modes) - 1)].lower()
        context.workspace.status_text_set(
            f"PHRT replay '{self._camera.name}' {mode} ({self._mode_index + 1}/{len(self._modes)}): {text}"
            f"  -  Esc to stop (rendered frames are kept)")


CLASSES = (PHRT_OT_replay_path,)
