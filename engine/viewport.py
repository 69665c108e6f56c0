"""The 3D viewport: PHRT's image in Rendered shading, and the decision overlay.

Rendered shading (``view_update`` / ``view_draw`` of the engine): the frame is
rendered through the same stages as a final frame (``extract`` snapshot ->
``gpu.frame`` GPU frame -> ``FrameRenderer`` selection, trace, GLSL lighting and
composite), seen from the viewport's view and projection matrices at a reduced
resolution, then the frame's GPU texture is drawn through Blender's display
transform.  Every cached GPU resource (shaders, meshes, shadow maps) is reused, so
orbiting a static scene costs a G-buffer and lighting pass; the image is rendered
again only when the depsgraph or the view changed.

The overlay (any shading mode): each element of the last final frame
(``session.last_frame().rows``) gets a coloured box by its decision -
``overlay_colors(rows)`` is the tested data, ``draw_overlay`` the GPU drawing,
which needs a window (never runs in background mode).

Only the overlay's draw handler reads ``bpy.context`` (draw handlers get no context).
"""
from __future__ import annotations

import dataclasses
import math
import time
import types

import numpy as np

from ..phrt_addon import naming
from ..phrt_addon.frame import FrameRenderer
from ..phrt_addon.scene.snapshot import Camera
from . import extract, final, session

# What each decision looks like in the overlay (linear RGBA).  Elements that are
# not candidates get no box: the overlay shows what the designer tagged.
OVERLAY_PALETTE = {
    "selected": (0.20, 0.90, 0.30, 1.0),
    "reduced_rate": (0.85, 0.95, 0.20, 1.0),
    "over_budget": (1.00, 0.55, 0.10, 1.0),
    "over_area": (0.70, 0.30, 1.00, 1.0),
    "not_visible": (0.50, 0.50, 0.50, 1.0),
}
# Legend entries for the panel: (decision, label, Blender icon of a matching colour).
OVERLAY_LEGEND = (
    ("selected", "Ray traced", "STRIP_COLOR_04"),
    ("reduced_rate", "Traced at half/quarter rate", "STRIP_COLOR_03"),
    ("over_budget", "Over budget", "STRIP_COLOR_02"),
    ("over_area", "Over area", "STRIP_COLOR_06"),
    ("not_visible", "Not visible", "STRIP_COLOR_09"),
)
# The viewport image has at most this many pixels (about 640x360): llvmpipe
# renders that in 0.1-0.3 s; a real GPU much faster.  It is scaled to the region.
VIEWPORT_MAX_PIXELS = 640 * 360


def decision(row) -> str | None:
    """The overlay decision of one selection row: a key of OVERLAY_PALETTE, or None
    for a non-candidate (or a row with an unknown reason)."""
    if bool(row.get("selected")):
        rate = row.get("rate")
        return "reduced_rate" if rate is not None and rate != "" and 0 < float(rate) < 1 else "selected"
    reason = row.get("reason") or ""
    return reason if reason in OVERLAY_PALETTE else None


def overlay_colors(rows) -> dict:
    """``{element_name: rgba}`` for the candidate elements of ``rows`` (selection rows
    with at least ``element``, ``selected`` and ``reason``)."""
    colors = {}
    for row in rows:
        key = decision(row)
        if key is not None:
            colors[str(row["element"])] = OVERLAY_PALETTE[key]
    return colors


def overlay_boxes(depsgraph, colors) -> list:
    """``[(rgba, corners (8, 3) world space)]``: the bounding box of every drawn
    object or instance whose element (or one of its material elements) has a colour.
    A material element's box is drawn 4% larger so it stays apart from its object's."""
    if not colors:
        return []
    material_colors = {}  # element base name -> colours of its material elements
    for element, color in colors.items():
        base = naming.base_element(element)
        if base is not None:
            material_colors.setdefault(base, []).append(color)
    boxes = []
    for instance in depsgraph.object_instances:
        obj = instance.object
        if obj.type not in extract.MESH_CONVERTIBLE:
            continue
        base = extract.instance_element_name(instance)
        entries = [(1.0, colors[base])] if base in colors else []
        entries += [(1.04, color) for color in material_colors.get(base, ())]
        if not entries:
            continue
        local = np.array([tuple(corner) for corner in obj.bound_box], dtype=np.float64)
        matrix = np.array(instance.matrix_world, dtype=np.float64)
        centre = local.mean(axis=0)
        for scale, color in entries:
            corners = centre + (local - centre) * scale
            boxes.append((color, corners @ matrix[:3, :3].T + matrix[:3, 3]))
    return boxes


# Blender's bound_box corner order: the 12 edges of the box.
_BOX_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))


def draw_overlay():
    """SpaceView3D POST_VIEW handler: boxes coloured by the last frame's decisions."""
    import bpy
    if bpy.app.background:
        return
    context = bpy.context
    window_manager = context.window_manager
    if not getattr(window_manager, "phrt_overlay", False):
        return
    space = context.space_data
    if space is None or space.type != "VIEW_3D" or not space.overlay.show_overlays:
        return
    boxes = overlay_boxes(context.evaluated_depsgraph_get(), overlay_colors(session.last_frame().rows))
    if not boxes:
        return
    import gpu
    from gpu_extras.batch import batch_for_shader
    shader = gpu.shader.from_builtin("UNIFORM_COLOR")
    gpu.state.blend_set("ALPHA")
    gpu.state.line_width_set(2.0)
    try:
        for color, corners in boxes:
            lines = [tuple(corners[index]) for edge in _BOX_EDGES for index in edge]
            batch = batch_for_shader(shader, "LINES", {"pos": lines})
            shader.uniform_float("color", color)
            batch.draw(shader)
    finally:
        gpu.state.line_width_set(1.0)
        gpu.state.blend_set("NONE")


def add_overlay_handler():
    """Install the overlay's draw handler (once; nothing to draw in background mode)."""
    import bpy
    engine_session = session.current()
    if engine_session.overlay_handle is None and not bpy.app.background:
        engine_session.overlay_handle = bpy.types.SpaceView3D.draw_handler_add(draw_overlay, (), "WINDOW",
                                                                               "POST_VIEW")


def remove_overlay_handler():
    import bpy
    engine_session = session.current()
    if engine_session.overlay_handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(engine_session.overlay_handle, "WINDOW")
        engine_session.overlay_handle = None


# -- Rendered shading ------------------------------------------------------------

def preview_size(region_width: int, region_height: int, max_pixels: int = VIEWPORT_MAX_PIXELS) -> tuple[int, int]:
    """The render size for a viewport region: its aspect, at most ``max_pixels``."""
    region_width, region_height = max(1, int(region_width)), max(1, int(region_height))
    scale = min(1.0, math.sqrt(max_pixels / (region_width * region_height)))
    return max(1, round(region_width * scale)), max(1, round(region_height * scale))


class _ViewCamera:
    """Stands in for the camera object ``extract.read_camera`` reads, so a snapshot can be
    built for the viewport's view when the scene has no camera (the snapshot's camera is
    then replaced by the exact one built from the matrices)."""

    def __init__(self, view_matrix, window_matrix, ortho, clip_start, clip_end):
        self.matrix_world = np.linalg.inv(np.asarray(view_matrix, dtype=np.float64))
        self.data = types.SimpleNamespace(type="ORTHO" if ortho else "PERSP", clip_start=clip_start,
                                          clip_end=clip_end)
        self._projection = np.asarray(window_matrix, dtype=np.float64)

    def evaluated_get(self, depsgraph):
        return self

    def calc_matrix_camera(self, depsgraph, **kwargs):
        return self._projection


def view_camera(view_matrix, window_matrix, width, height, ortho=False, clip_start=0.01, clip_end=1000.0) -> Camera:
    """A snapshot camera looking like the viewport: ``view_matrix`` (world -> view) and
    ``window_matrix`` (view -> clip) are the RegionView3D's."""
    return Camera(matrix_world=np.linalg.inv(np.asarray(view_matrix, dtype=np.float64)),
                  projection=np.array(window_matrix, dtype=np.float64), width=int(width), height=int(height),
                  ortho=bool(ortho), clip_start=float(clip_start), clip_end=float(clip_end))


def render_view(depsgraph, camera: Camera, renderer: FrameRenderer, read_back: bool = True):
    """Render one PHRT frame of ``depsgraph`` seen by ``camera``; needs a GPU context
    (``view_draw``, or ``render()`` of an engine with ``bl_use_gpu_context``).
    Returns the ``FrameResult``: ``passes.combined`` is the image read back ((h, w, 4), bottom
    row first), or None without ``read_back``; the GPU keeps it in the frame target "combined"
    (``the session's GPU resources' target``) until the next frame is drawn."""
    start = time.perf_counter()
    stand_in = _ViewCamera(camera.view_matrix, camera.projection, camera.ortho, camera.clip_start, camera.clip_end)
    snapshot = extract.extract(depsgraph, camera_override=stand_in)
    snapshot = dataclasses.replace(snapshot, camera=camera)
    extract_ms = (time.perf_counter() - start) * 1000.0
    gpu_frame = final.rasterize(snapshot)
    gpu_frame.read_combined = read_back
    result = renderer.render(snapshot, gpu_frame)
    result.stats["extract_ms"] = extract_ms
    result.problems = list(snapshot.problems)
    return result


class ViewportRender:
    """Rendered shading of one viewport (one engine instance per viewport).

    ``update()`` (from ``view_update``) only marks the image stale; ``draw()`` (from
    ``view_draw``) renders again when the image is stale or the view changed, then
    draws the cached texture over the region."""

    def __init__(self):
        self.renderer = FrameRenderer()
        self.stale = True
        self.view_key = None
        self.image_frame = None  # resources.frames_drawn when this view's image was drawn
        self.size = None

    def update(self, depsgraph):
        self.stale = True

    def draw(self, engine, context, depsgraph):
        import gpu
        from gpu_extras.presets import draw_texture_2d

        region = context.region
        region_3d = context.region_data
        space = context.space_data
        width, height = preview_size(region.width, region.height)
        view_matrix = np.array(region_3d.view_matrix, dtype=np.float64)
        window_matrix = np.array(region_3d.window_matrix, dtype=np.float64)
        key = (view_matrix.round(6).tobytes(), window_matrix.round(6).tobytes(), width, height)
        resources = session.current().resources
        if self.image_frame is not None and self.image_frame != resources.frames_drawn:
            self.stale = True  # another render drew into the frame targets since: draw ours again
        if self.stale or key != self.view_key:
            # Whatever happens, this view is done: a failing scene is not re-rendered on every redraw.
            self.stale, self.view_key, self.image_frame = False, key, None
            camera = view_camera(view_matrix, window_matrix, width, height, ortho=not region_3d.is_perspective,
                                 clip_start=getattr(space, "clip_start", 0.01),
                                 clip_end=getattr(space, "clip_end", 1000.0))
            viewport = gpu.state.viewport_get()
            try:
                result = render_view(depsgraph, camera, self.renderer, read_back=False)
            finally:
                gpu.state.viewport_set(*viewport)
            self.image_frame = resources.frames_drawn
            self.size = (width, height)
            engine.update_stats("PHRT", f"{result.stats['total_ms']:.0f} ms, "
                                        f"{result.stats['n_selected']}/{result.stats['n_visible']} traced")
        # The frame's own GPU target is drawn: nothing is read back (textures are shared between
        # the render and the window's context).  No reference to it is kept here: GPU objects
        # belong to the session's resources alone, which frees them deliberately.
        texture = resources.target("combined", self.size) if self.image_frame is not None else None
        if texture is None:
            return
        gpu.state.blend_set("ALPHA_PREMULT")
        engine.bind_display_space_shader(depsgraph.scene)
        try:
            draw_texture_2d(texture, (0, 0), region.width, region.height)
        finally:
            engine.unbind_display_space_shader()
            gpu.state.blend_set("NONE")
            del texture
