"""PHRT's Blender render engine: a thin router around ``engine/final.py``.

Every callback turns an exception into ``report({'ERROR'})`` + ``error_set`` so
the caller of ``bpy.ops.render.render()`` gets a ``RuntimeError`` with the
message, instead of a silently black image.
"""
import bpy

from ..phrt_addon.schema import PASSES
from . import final, session



class PHRTRenderEngine(bpy.types.RenderEngine):
    bl_idname = "PHRT"
    bl_label = "PHRT Hybrid"
    bl_use_gpu_context = True
    bl_use_shading_nodes_custom = False  # designers keep editing Principled BSDF materials
    bl_use_preview = False
    bl_use_postprocess = True

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.session = session.current()  # what outlives this instance (caches, GPU objects, last frame)
        self.final = None
        self.viewport = None  # engine/viewport.ViewportRender, created by the first viewport callback

    def render(self, depsgraph):
        try:
            if self.final is None:
                self.final = final.FinalRender(self)
            # numpy's BLAS threads would spin on the cores the GPU driver renders with.
            with self.session.blas.limited(1):
                self.final.render(depsgraph)
        except Exception as error:  # reported to the caller, never swallowed
            message = f"PHRT: {error}"
            final.log_exception(error)
            self.report({"ERROR"}, message)
            self.error_set(message)

    def view_update(self, context, depsgraph):
        """Rendered shading: something changed; the next view_draw renders again."""
        from . import viewport
        try:
            if self.viewport is None:
                self.viewport = viewport.ViewportRender()
            with self.session.blas.limited(1):
                self.viewport.update(depsgraph)
        except Exception as error:  # shown in the viewport, never raised into Blender's draw loop
            final.log_exception(error)
            self.update_stats("PHRT", f"Error: {error}")

    def view_draw(self, context, depsgraph):
        """Rendered shading: draw PHRT's image of the viewport's view (see engine/viewport.py)."""
        from . import viewport
        try:
            if self.viewport is None:
                self.viewport = viewport.ViewportRender()
            with self.session.blas.limited(1):
                self.viewport.draw(self, context, depsgraph)
        except Exception as error:  # shown in the viewport, never raised into Blender's draw loop
            final.log_exception(error)
            self.update_stats("PHRT", f"Error: {error}")

    def update_render_passes(self, scene=None, renderlayer=None):
        for name, channels, chan_id, pass_type in PASSES:
            self.register_pass(scene, renderlayer, name, channels, chan_id, pass_type)


def _compat_panels():
    """Blender's own panels that apply to PHRT (dimensions, output, camera, light, material...)."""
    wanted_prefixes = ("RENDER_PT_format", "RENDER_PT_frame_range", "RENDER_PT_time_stretching",
                       "RENDER_PT_stereoscopy", "RENDER_PT_output", "RENDER_PT_encoding",
                       "RENDER_PT_post_processing", "RENDER_PT_stamp", "RENDER_PT_color_management",
                       "DATA_PT_camera", "DATA_PT_lens", "DATA_PT_context_camera", "DATA_PT_camera_dof",
                       "DATA_PT_context_light", "DATA_PT_light", "DATA_PT_EEVEE_light", "DATA_PT_spot",
                       "DATA_PT_area", "DATA_PT_context_mesh", "DATA_PT_normals", "DATA_PT_uv_texture",
                       "DATA_PT_vertex_groups", "DATA_PT_shape_keys", "DATA_PT_customdata",
                       "MATERIAL_PT_preview", "EEVEE_MATERIAL_PT_context_material", "EEVEE_MATERIAL_PT_surface",
                       "MATERIAL_PT_viewport", "WORLD_PT_context_world", "EEVEE_WORLD_PT_surface",
                       "VIEWLAYER_PT_layer_passes", "VIEWLAYER_PT_layer", "OBJECT_PT_visibility")
    for name in wanted_prefixes:
        panel = getattr(bpy.types, name, None)
        if panel is not None and hasattr(panel, "COMPAT_ENGINES"):
            yield panel


@bpy.app.handlers.persistent
def _release_on_load(*_args):
    """Another file: nothing cached for the old one (GPU resources, Embree scenes) is kept."""
    final.release_caches()


def register():
    bpy.utils.register_class(PHRTRenderEngine)
    if _release_on_load not in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.append(_release_on_load)
    for panel in _compat_panels():
        panel.COMPAT_ENGINES.add(PHRTRenderEngine.bl_idname)


def unregister():
    if _release_on_load in bpy.app.handlers.load_post:
        bpy.app.handlers.load_post.remove(_release_on_load)
    for panel in _compat_panels():
        panel.COMPAT_ENGINES.discard(PHRTRenderEngine.bl_idname)
    bpy.utils.unregister_class(PHRTRenderEngine)
    final.release_caches()
