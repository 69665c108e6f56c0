"""Replaying a camera path: one RUN_DIR per mode (CONTRACT.md section 4).

Shared by the ``phrt.replay_path`` operator, the ``phrt`` command and the demo,
so the same input gives the same files whichever way a designer starts it.

A camera path is an animated camera object; its frame range is its
animation's (keyframes, or the scene range for a Follow Path constraint).
Frames are rendered one ``render.render()`` call at a time, with the state a
replay carries (Embree scenes uploaded once, cost model, last selection) held
by a ``ReplaySession``; after each frame the image is written and the logs are
flushed, so a cancelled replay leaves complete frames and logs only.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import bpy

from ..phrt_addon import runlog
from . import extract, final

MODES = ("RASTER", "HYBRID", "RAYTRACE")
IMAGE_FORMATS = ("exr", "png", "none")


class ReplayError(ValueError):
    """Bad replay input: the message says what is wrong and how to fix it."""


def camera_paths(scene) -> list:
    """Camera objects of the scene that can be replayed, the scene's own order first
    (``scene['phrt_paths']``), then the active camera, then the others by name."""
    cameras = [obj for obj in scene.objects if obj.type == "CAMERA"]
    order = [name for name in str(scene.get("phrt_paths", "")).split(",") if name]
    ranked = [bpy.data.objects[name] for name in order if name in bpy.data.objects
              and bpy.data.objects[name].type == "CAMERA"]
    if scene.camera is not None and scene.camera not in ranked and scene.camera.type == "CAMERA":
        ranked.append(scene.camera)
    ranked += sorted((c for c in cameras if c not in ranked), key=lambda c: c.name)
    return ranked


def find_path(scene, name=None):
    paths = camera_paths(scene)
    if not paths:
        raise ReplayError(f"scene '{scene.name}' has no camera: add an animated camera to replay")
    if name is None:
        return paths[0]
    for camera in paths:
        if camera.name == name:
            return camera
    raise ReplayError(f"no camera path '{name}' in scene '{scene.name}'; "
                      f"its paths are: {', '.join(c.name for c in paths)}")


def path_frame_range(scene, camera) -> tuple[int, int]:
    """The camera's animated range, clipped to nothing: keyframes if it has them,
    otherwise the scene's frame range."""
    action = camera.animation_data.action if camera.animation_data else None
    if action is not None:
        start, end = action.frame_range
        return int(round(start)), int(round(end))
    return int(scene.frame_start), int(scene.frame_end)


def parse_frames(text, default_range) -> tuple[int, int]:
    if text is None:
        return default_range
    parts = str(text).split("-")
    try:
        if len(parts) == 1:
            start = end = int(parts[0])
        elif len(parts) == 2:
            start, end = int(parts[0]), int(parts[1])
        else:
            raise ValueError
    except ValueError:
        raise ReplayError(f"malformed frame range '{text}': use A-B with integers, e.g. --frames 1-120") from None
    if end < start:
        raise ReplayError(f"frame range '{text}' ends before it starts: use A-B with A <= B")
    return start, end


def _set_image_format(scene, images):
    settings = scene.render.image_settings
    if images == "exr":
        if hasattr(settings, "media_type"):  # Blender 5.0+
            settings.media_type = "MULTI_LAYER_IMAGE"
        else:
            settings.file_format = "OPEN_EXR_MULTILAYER"
        settings.exr_codec = "ZIP"
        settings.color_depth = "32"
    elif images == "png":
        if hasattr(settings, "media_type"):
            settings.media_type = "IMAGE"
        settings.file_format = "PNG"
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


def replay(scene, camera, frame_range, mode, run_dir, *, images="exr", budget_ms=None, resolution=None,
           scene_label=None, on_progress=None, should_stop=None) -> ReplayResult:
    """Render ``frame_range`` of ``camera`` in ``mode`` into ``run_dir``.

    ``on_progress(done, total, frame_ms)`` is called after each frame;
    ``should_stop()`` is polled between frames (Esc in the UI)."""
    mode = mode.upper()
    if mode not in MODES:
        raise ReplayError(f"unknown mode '{mode}': use one of {', '.join(m.lower() for m in MODES)}")
    if images not in IMAGE_FORMATS:
        raise ReplayError(f"unknown image format '{images}': use exr, png or none")
    if budget_ms is not None and not budget_ms >= 0:
        raise ReplayError(f"budget must be a number of milliseconds >= 0, not {budget_ms}")
    run_dir = Path(run_dir)
    frames_dir = run_dir / runlog.FRAMES_DIR
    try:
        frames_dir.mkdir(parents=True, exist_ok=True)
        probe = run_dir / ".phrt-write-test"
        probe.write_text("")
        probe.unlink()
    except OSError as error:
        raise ReplayError(f"cannot write to output folder '{run_dir}': {error.strerror or error}") from None

    settings = extract.read_settings(scene)
    settings.mode = mode
    if budget_ms is not None:
        settings.budget_ms = float(budget_ms)
    render = scene.render
    saved = {"camera": scene.camera, "frame": scene.frame_current, "filepath": render.filepath,
             "res": (render.resolution_x, render.resolution_y, render.resolution_percentage),
             "engine": render.engine, "use_ext": render.use_file_extension}
    image_saved = {key: getattr(render.image_settings, key) for key in
                   ("file_format", "color_depth", "color_mode") if hasattr(render.image_settings, key)}
    if hasattr(render.image_settings, "media_type"):
        image_saved = {"media_type": render.image_settings.media_type, **image_saved}
    scene.camera = camera
    render.engine = "PHRT"
    if resolution is not None:
        render.resolution_x, render.resolution_y = resolution
        render.resolution_percentage = 100
    _set_image_format(scene, images)
    render.use_file_extension = True
    start, end = frame_range
    total = end - start + 1
    done = 0
    cancelled = False
    summary = None
    try:
        # Leaving the RunLog without close() (an error) keeps the complete rows written so far.
        with runlog.RunLog(run_dir, extra_frame_columns=EXTRA_FRAME_COLUMNS) as log, \
                final.ReplaySession(settings_override=settings, camera=camera) as session:
            for frame in range(start, end + 1):
                if should_stop is not None and should_stop():
                    cancelled = True
                    break
                scene.frame_set(frame)
                render.filepath = str(frames_dir / f"{frame:04d}")
                begin = time.perf_counter()
                bpy.ops.render.render(write_still=images != "none")
                wall_ms = (time.perf_counter() - begin) * 1000.0
                result = session.last_result
                if result is None:
                    if should_stop is not None and should_stop():
                        cancelled = True  # stopped in the middle of this frame: it is not kept
                        break
                    raise ReplayError(f"frame {frame} did not render (see the messages above)")
                row = {key: result.stats.get(key) for key in runlog.FRAME_COLUMNS}
                row.update({key: result.stats.get(key) for key in EXTRA_FRAME_COLUMNS})
                row["wall_ms"] = wall_ms
                log.add_frame(row, result.selection_rows)
                session.last_result = None
                done += 1
                if on_progress is not None:
                    on_progress(done, total, result.stats["total_ms"])
            width, height = extract.resolution(scene)
            summary = log.close({
                "scene": scene_label or scene.name, "path": camera.name, "resolution": [width, height],
                "images": images, "frame_range": [start, end], "cancelled": cancelled,
                "cost_mode": settings.cost_mode, "selection_weight": settings.selection_weight,
                "max_area_fraction": settings.max_area_fraction, **versions()})
    finally:
        scene.camera = saved["camera"]
        scene.frame_set(saved["frame"])
        render.filepath = saved["filepath"]
        render.resolution_x, render.resolution_y, render.resolution_percentage = saved["res"]
        render.engine = saved["engine"]
        render.use_file_extension = saved["use_ext"]
        for key, value in image_saved.items():
            try:
                setattr(render.image_settings, key, value)
            except (TypeError, AttributeError):
                pass
    return ReplayResult(run_dir=run_dir, mode=mode, frames_done=done, cancelled=cancelled, summary=summary)


EXTRA_FRAME_COLUMNS = ("wall_ms", "extract_ms", "gpu_upload_ms", "upload_ms", "setup_ms", "shadow_rays", "reflection_rays",
                       "refraction_rays", "time_left_ms", "triangles")


def default_run_dir(out_root, scene_label, camera_name, mode) -> Path:
    return Path(out_root) / f"{scene_label}-{camera_name}-{mode.lower()}"
