"""Properties > Render with PHRT as the engine: the scene's renderer settings (``Scene.phrt``:
mode, budget with the frame rate it means, selection (and the paper's I, relevance and greedy order), max area, bounces,
cost model, shadow map size).  docs/properties.md says what each does."""

import bpy


def frame_rate_text(budget_ms: float) -> str:
    """The frame rate a frame budget means: ``'60 fps'``; ``'no budget'`` for 0."""
    if budget_ms <= 0:
        return "no budget"
    return f"{1000.0 / budget_ms:.3g} fps"


class PHRT_PT_render(bpy.types.Panel):
    """The scene's hybrid renderer settings."""

    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    bl_label = "PHRT Hybrid"
    COMPAT_ENGINES = {"PHRT"}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES

    def draw(self, context):
        layout = self.layout
        settings = context.scene.phrt
        layout.row().prop(settings, "mode", expand=True)
        layout.use_property_split = True
        layout.use_property_decorate = False
        column = layout.column()
        column.prop(settings, "use_budget_at")
        if settings.use_budget_at:
            column.prop(settings, "budget_at", text="Budget At (raster 0, ray traced 1)")
        else:
            row = column.row(align=True)
            row.prop(settings, "budget_ms", text="Budget (ms)")
            row.label(text=frame_rate_text(settings.budget_ms))
        column.prop(settings, "selection")
        tiers = column.row()
        tiers.active = settings.selection == "BENEFIT"
        tiers.prop(settings, "quality_tiers")
        paper = column.column()
        paper.active = settings.selection == "PAPER"  # the paper's knobs; BENEFIT has its own terms
        paper.prop(settings, "selection_weight", text="Selection Weight I")
        paper.prop(settings, "relevance")
        paper.prop(settings, "selection_order")
        column.prop(settings, "max_area_fraction", text="Max Area (of frame)")
        column.prop(settings, "max_bounces")
        column.prop(settings, "cost_mode")
        column.prop(settings, "shadow_map_size", text="Shadow Map (px)")


CLASSES = (PHRT_PT_render,)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
