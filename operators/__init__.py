"""PHRT operators: thin Blender skins over ``engine/runs/replay.py`` and the run logs.

- ``phrt.replay_path``: replay a camera path in one or more modes (``replay_path.py``);
- ``phrt.export_selection_log``: the heuristic's decisions as CSV or JSON (``selection_log.py``);
- ``phrt.copy_settings_to_selected``, ``phrt.refresh_candidates`` (``tagging.py``);
- ``phrt.advise_path``, ``phrt.apply_advice``: the tagging Advisor (``advisor.py``).
"""
import bpy

from . import advisor, replay_path, selection_log, tagging

CLASSES = tagging.CLASSES + replay_path.CLASSES + selection_log.CLASSES


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    advisor.register()


def unregister():
    advisor.unregister()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
