"""Tagging several objects at once, and refreshing the N panel's candidate list."""

import bpy
from bpy.props import EnumProperty

from ..engine import candidate_list
from ..properties import PHRT_ObjectSettings

# The per-element fields of Object.phrt and Material.phrt (docs/properties.md).
ELEMENT_FIELDS = tuple(PHRT_ObjectSettings.__annotations__)


def copy_element_settings(source, targets) -> int:
    """Copy the PHRT element fields of ``source`` (an Object.phrt or Material.phrt) to
    each of ``targets``; returns how many targets changed."""
    changed = 0
    for target in targets:
        if target == source:
            continue
        if any(getattr(target, name) != getattr(source, name) for name in ELEMENT_FIELDS):
            changed += 1
        for name in ELEMENT_FIELDS:
            setattr(target, name, getattr(source, name))
    return changed


class PHRT_OT_copy_settings_to_selected(bpy.types.Operator):
    """Apply the active object's PHRT settings (candidate, priority K, effects, cost Q) to every
    selected object, or the active material's to the materials of the selected objects"""

    bl_idname = "phrt.copy_settings_to_selected"
    bl_label = "Copy to Selected"
    bl_options = {"REGISTER", "UNDO"}

    source: EnumProperty(
        name="Source",
        items=(
            ("OBJECT", "Object", "Copy the active object's settings to the selected objects", 0),
            ("MATERIAL", "Material", "Copy the active material's settings to every material of the selected "
                                     "objects (materials are shared: other objects using them change too)", 1),
        ),
        default="OBJECT",
        description="Whose settings are copied",
    )

    @classmethod
    def poll(cls, context):
        return context.active_object is not None

    def execute(self, context):
        active = context.active_object
        selected = [obj for obj in context.selected_objects if obj != active]
        if self.source == "OBJECT":
            changed = copy_element_settings(active.phrt, [obj.phrt for obj in selected])
            what = "objects"
        else:
            material = active.active_material
            if material is None:
                self.report({"ERROR"}, f"PHRT: '{active.name}' has no active material to copy from")
                return {"CANCELLED"}
            targets = {slot.material for obj in selected for slot in obj.material_slots if slot.material is not None}
            targets.discard(material)
            changed = copy_element_settings(material.phrt, [target.phrt for target in targets])
            what = "materials"
        self.report({"INFO"}, f"PHRT: settings copied to {changed} {what}")
        return {"FINISHED"}


class PHRT_OT_refresh_candidates(bpy.types.Operator):
    """Rebuild the candidate list: every element of the scene with its settings and the last
    rendered frame's visibility V, cost C, relevance R and decision"""

    bl_idname = "phrt.refresh_candidates"
    bl_label = "Refresh Candidates"
    bl_options = {"REGISTER"}

    def execute(self, context):
        count = candidate_list.refresh(context.window_manager, context.scene)
        self.report({"INFO"}, f"PHRT: {count} elements listed")
        return {"FINISHED"}


CLASSES = (PHRT_OT_copy_settings_to_selected, PHRT_OT_refresh_candidates)
