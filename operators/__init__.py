"""PHRT operators: thin Blender skins over ``engine/runs/replay.py`` and the run logs.

- ``phrt.replay_path``: replay a camera path in one or more modes (``replay_path.py``);
- ``phrt.export_selection_log``: the heuristic's decisions as CSV or JSON (``selection_log.py``);
- ``phrt.copy_settings_to_selected``, ``phrt.refresh_candidates`` (``tagging.py``).
"""
import bpy

from . import replay_path, selection_log, tagging

CLASSES = tagging.CLASSES + replay_path.CLASSES + selection_log.CLASSES


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
