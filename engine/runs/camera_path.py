"""Camera paths of a scene: which cameras can be replayed, a path found by name, its frame range,
and a frame range given as text (``A-B``).  A camera path is an animated camera object; its frame
range is its animation's (keyframes, or the scene range for a Follow Path constraint)."""
from __future__ import annotations

import bpy


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
    check_frame_range(start, end)
    return start, end


def check_frame_range(start, end):
    """ReplayError unless the frame range ``start``-``end`` runs forward (the one check of it: the
    replay, both operators and the ``phrt`` command ask it)."""
    if end < start:
        raise ReplayError(f"frame range {start}-{end} ends before it starts: give a last frame >= the first")
