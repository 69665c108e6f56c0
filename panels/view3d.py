"""The 3D view sidebar (N panel), tab ``PHRT``: what a level designer tags and tunes.

- Element: the active object's candidate tag, priority K, effects and cost Q, and
  (sub-panel) the active material's; both copy to the selection in one click.
- Candidates: every element with K and the last frame's R and decision; the overlay.
- Replay: a camera path over a frame range in several modes; export the selection log.
- Advisor: what each tag is worth per ms along the active camera's path, one recommendation per
  (element, effect) item, applied in one click (one undo step);
- Last Render: timings of the last frame and the problems it reported (skipped objects).

Every panel shares ``PHRT_Panel``: shown only when the render engine is PHRT.  The scene's
renderer settings are in Properties > Render (``panels/render.py``).
"""

import textwrap

import bpy

from ..engine import candidate_list, session, viewport
from ..engine.runs import camera_path
from ..operators import advisor
from . import candidates


class PHRT_Panel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "PHRT"
    COMPAT_ENGINES = {"PHRT"}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES


def _draw_element_settings(layout, settings):
    """The per-element fields of Object.phrt / Material.phrt (candidate is in the header)."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    column = layout.column()
    column.active = settings.candidate
    column.prop(settings, "priority", text="Priority K")
    column.prop(settings, "rt_cost", text="Cost Q")
    effects = column.column(heading="Ray Trace", align=True)
    effects.prop(settings, "shadows")
    effects.prop(settings, "reflections")
    effects.prop(settings, "refractions")


class PHRT_PT_element(PHRT_Panel, bpy.types.Panel):
    """The active object as a ray tracing element."""

    bl_label = "Element"
    bl_order = 0

    def draw_header(self, context):
        obj = context.object
        if obj is not None:
            self.layout.prop(obj.phrt, "candidate", text="")

    def draw(self, context):
        layout = self.layout
        obj = context.object
        if obj is None:
            layout.label(text="Select an object to tag it", icon="INFO")
            return
        layout.label(text=obj.name, icon="OBJECT_DATA")
        _draw_element_settings(layout, obj.phrt)
        row = layout.row()
        row.enabled = len(context.selected_objects) > 1
        op = row.operator("phrt.copy_settings_to_selected", icon="PASTEDOWN")
        op.source = "OBJECT"


class PHRT_PT_element_material(PHRT_Panel, bpy.types.Panel):
    """The active material's faces as their own element (e.g. the glass of a window)."""

    bl_label = "Material"
    bl_parent_id = "PHRT_PT_element"

    @classmethod
    def poll(cls, context):
        return super().poll(context) and context.object is not None and context.object.type in {
            "MESH", "CURVE", "SURFACE", "META", "FONT"}

    def draw_header(self, context):
        material = context.object.active_material
        if material is not None:
            self.layout.prop(material.phrt, "candidate", text="")

    def draw(self, context):
        layout = self.layout
        obj = context.object
        layout.template_list("MATERIAL_UL_matslots", "phrt", obj, "material_slots", obj, "active_material_index",
                             rows=2)
        material = obj.active_material
        if material is None:
            layout.label(text="No material in this slot", icon="INFO")
            return
        _draw_element_settings(layout, material.phrt)
        row = layout.row()
        row.enabled = len(context.selected_objects) > 1
        op = row.operator("phrt.copy_settings_to_selected", text="Copy to Selected's Materials", icon="PASTEDOWN")
        op.source = "MATERIAL"


class PHRT_PT_candidates(PHRT_Panel, bpy.types.Panel):
    """Every element, its K and the last frame's decision."""

    bl_label = "Candidates"
    bl_order = 2

    def draw(self, context):
        layout = self.layout
        window_manager = context.window_manager
        row = layout.row()
        row.template_list("PHRT_UL_candidates", "", window_manager, "phrt_candidates", window_manager,
                          "phrt_candidate_index", rows=4)
        row.operator("phrt.refresh_candidates", text="", icon="FILE_REFRESH")
        items = window_manager.phrt_candidates
        index = window_manager.phrt_candidate_index
        if 0 <= index < len(items):
            _draw_candidate_details(layout.box(), items[index])
        row = layout.row()
        row.prop(window_manager, "phrt_overlay", icon="OVERLAY")
        if window_manager.phrt_overlay:
            legend = layout.grid_flow(columns=2, align=True)
            for _, label, icon in viewport.OVERLAY_LEGEND:
                legend.label(text=label, icon=icon)


def _draw_candidate_details(layout, item):
    text, icon = candidates.DECISIONS[candidates.decision_key(item.rendered, item.selected, item.reason)]
    layout.label(text=item.name, icon=icon)
    column = layout.column(align=True)
    settings = candidates.live_settings(item)
    priority, effects = ((settings.priority, candidate_list.effects_text(settings)) if settings is not None
                         else (item.priority, item.effects))
    column.label(text=f"Priority K {priority:.3g}   Effects {effects}")
    if item.rendered:
        column.label(text=f"V {item.visibility:.3g}   C {item.cost:.3g}   R {item.relevance:.3g}")
    column.label(text=text)


class PHRT_PT_replay(PHRT_Panel, bpy.types.Panel):
    """Replay a camera path and write the run logs."""

    bl_label = "Replay"
    bl_order = 3

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        settings = scene.phrt_replay
        layout.use_property_split = True
        layout.use_property_decorate = False
        column = layout.column()
        column.prop(settings, "camera")
        camera = settings.camera
        if camera is None:
            paths = camera_path.camera_paths(scene)
            camera = paths[0] if paths else None
            column.label(text=f"Path: {camera.name}" if camera else "The scene has no camera",
                         icon="CAMERA_DATA" if camera else "ERROR")
        column.prop(settings, "use_path_range")
        frames = column.column(align=True)
        if settings.use_path_range:
            if camera is not None:
                start, end = camera_path.path_frame_range(scene, camera)
                frames.label(text=f"Frames {start}-{end}")
        else:
            frames.prop(settings, "frame_start")
            frames.prop(settings, "frame_end")
        column.prop(settings, "modes")
        column.prop(settings, "images")
        column.prop(settings, "output_dir")
        row = layout.row()
        row.enabled = camera is not None and bool(settings.modes)
        row.scale_y = 1.3
        op = row.operator("phrt.replay_path", icon="RENDER_ANIMATION")
        op.path = settings.camera.name if settings.camera else ""
        if not settings.use_path_range:
            op.frame_start, op.frame_end = settings.frame_start, settings.frame_end
        op.modes = settings.modes
        op.output_dir = settings.output_dir
        op.images = settings.images
        layout.operator("phrt.export_selection_log", icon="EXPORT")


class PHRT_PT_last_render(PHRT_Panel, bpy.types.Panel):
    """The last rendered frame: stage timings and the problems it reported."""

    bl_label = "Last Render"
    bl_order = 5

    def draw(self, context):
        layout = self.layout
        stats = session.last_frame().stats
        if not stats:
            layout.label(text="Nothing rendered yet (F12)", icon="INFO")
        else:
            column = layout.column(align=True)
            column.label(text=f"Frame {stats.get('frame')}, {str(stats.get('mode', '')).lower()}: "
                              f"{stats.get('total_ms', 0.0):.0f} ms of {stats.get('budget_ms', 0.0):g} ms budget")
            column.label(text=f"Raster {stats.get('raster_ms', 0.0):.0f}, select {stats.get('select_ms', 0.0):.0f}, "
                              f"trace {stats.get('trace_ms', 0.0):.0f}, composite "
                              f"{stats.get('composite_ms', 0.0):.0f} ms")
            column.label(text=f"Ray traced {stats.get('n_selected', 0)} of {stats.get('n_visible', 0)} visible, "
                              f"{stats.get('n_candidates', 0)} candidates")
        problems = session.last_frame().problems
        box = layout.box()
        if not problems:
            box.label(text="No problems", icon="CHECKMARK")
            return
        box.label(text=f"{len(problems)} problem{'s' if len(problems) != 1 else ''}:", icon="ERROR")
        column = box.column(align=True)
        for problem in problems:
            column.label(text=problem)


class PHRT_UL_advice(bpy.types.UIList):
    """The last advice's items: element / effect, its recommendation, benefit per ms."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_property, index=0, flt_flag=0):
        row = layout.row(align=True)
        row.label(text=f"{item.element} / {item.effect}", icon="OBJECT_DATA" if item.tagged else "GHOST_ENABLED")
        row.label(text=item.recommendation.replace("_", " ") + (" (applied)" if item.applied else ""),
                  icon=advisor.ICONS.get(item.recommendation, "QUESTION"))


class PHRT_PT_advisor(PHRT_Panel, bpy.types.Panel):
    """The tagging Advisor for the active camera's path."""

    bl_label = "Advisor"
    bl_order = 4
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        window_manager = context.window_manager
        camera = context.scene.camera
        layout.label(text=f"Path: {camera.name}" if camera else "No active camera", icon="CAMERA_DATA")
        row = layout.row()
        row.scale_y = 1.2
        row.operator("phrt.advise_path", icon="VIEWZOOM")
        items = window_manager.phrt_advice
        if not len(items):
            layout.label(text="Run the advice to list each tag's worth", icon="INFO")
            return
        layout.template_list("PHRT_UL_advice", "", window_manager, "phrt_advice", window_manager,
                             "phrt_advice_index", rows=5)
        index = window_manager.phrt_advice_index
        if 0 <= index < len(items):
            item = items[index]
            box = layout.box()
            box.label(text=f"{item.recommendation.replace('_', ' ')}: {item.benefit_per_ms:.5f} LDR-FLIP per ms",
                      icon=advisor.ICONS.get(item.recommendation, "QUESTION"))
            column = box.column(align=True)
            for line in textwrap.wrap(item.reason, 60):
                column.label(text=line)
            row = box.row()
            row.enabled = item.recommendation != "keep" and not item.applied
            row.operator("phrt.apply_advice", icon="CHECKMARK").index = index
        if window_manager.phrt_advice_folder:
            layout.label(text=window_manager.phrt_advice_folder, icon="FILE_FOLDER")


PANELS = (PHRT_PT_element, PHRT_PT_element_material, PHRT_PT_candidates, PHRT_PT_replay, PHRT_PT_advisor,
          PHRT_PT_last_render)
CLASSES = (PHRT_UL_advice, *PANELS)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    viewport.add_overlay_handler()


def unregister():
    viewport.remove_overlay_handler()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
