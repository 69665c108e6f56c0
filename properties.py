"""Every Blender property of PHRT (docs/properties.md): what designers tag on objects and
materials (``Object.phrt``, ``Material.phrt``), the scene-wide settings of the hybrid
renderer (``Scene.phrt``), the Replay panel's settings (``Scene.phrt_replay``) and the
UI's own state (``WindowManager.phrt_candidates``, ``phrt_candidate_index``,
``phrt_overlay``), with the enum items the operators share.

Each PropertyGroup attaches itself in its ``register()`` classmethod and detaches in
``unregister()``.  Imports only downward: the core and ``engine/``.
"""
import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, IntProperty,
                       PointerProperty, StringProperty)

from .engine import candidate_list
from .phrt_addon import defaults, schema

# '//' (relative to the .blend file) must be declared from Blender 4.5 (the oldest supported) on.
BLEND_RELATIVE_PATH = {"PATH_SUPPORTS_BLEND_RELATIVE"}
# The modes a replay renders (a set: ENUM_FLAG items are powers of two).
MODE_FLAG_ITEMS = tuple((identifier, name, description, 1 << index)
                        for index, (identifier, name, description) in enumerate(schema.MODE_ITEMS))
IMAGE_ITEMS = (
    ("EXR", "OpenEXR", "Multilayer EXR with every PHRT pass (needed by 'phrt report' error metrics)", 0),
    ("PNG", "PNG", "8-bit sRGB PNG of the combined image", 1),
    ("NONE", "None", "Logs only, no images", 2),
)


def _enum_items(items):
    """EnumProperty items with explicit indices from a ``schema`` table (identifier, name, description)."""
    return tuple((identifier, name, description, index) for index, (identifier, name, description) in enumerate(items))


def _refresh_candidate_list(self, context):
    """Tagging or untagging updates the N panel's candidate list at once (when the panels are
    registered; they own the list)."""
    if context is None or not hasattr(bpy.types.WindowManager, "phrt_candidates"):
        return
    window_manager, scene = getattr(context, "window_manager", None), getattr(context, "scene", None)
    if window_manager is not None and scene is not None:
        candidate_list.refresh(window_manager, scene)


def _element_fields(owner):
    """The per-element fields, shared by objects and materials."""
    return {
        "candidate": BoolProperty(
            name="Ray Tracing Candidate",
            description=f"Tag this {owner} as an element that PHRT may ray trace when the heuristic picks it",
            default=False,
            update=_refresh_candidate_list,
        ),
        "priority": FloatProperty(
            name="Priority (K)",
            description="The paper's K: how much this element matters relative to the others (0 = never worth tracing)",
            default=1.0, min=0.0, soft_max=10.0,
        ),
        "shadows": BoolProperty(
            name="Shadows",
            description="Ray trace the shadows this element casts (on any surface), instead of shadow-mapping them",
            default=True,
        ),
        "reflections": BoolProperty(
            name="Reflections",
            description="Ray trace reflections on this element's surface",
            default=True,
        ),
        "refractions": BoolProperty(
            name="Refractions",
            description="Ray trace refraction through this element (transparency is refraction with IOR 1)",
            default=True,
        ),
        "rt_cost": FloatProperty(
            name="Cost Multiplier (Q)",
            description="The paper's Q: how costly the selection takes this element to be, as a multiple of its "
                        "measured ray tracing cost (the frame's time is still planned with the real cost)",
            default=1.0, min=1e-3, soft_max=10.0,
        ),
    }


class PHRT_ObjectSettings(bpy.types.PropertyGroup):
    """Whole-object element tags (Object.phrt)."""

    __annotations__ = _element_fields("object")

    @classmethod
    def register(cls):
        bpy.types.Object.phrt = PointerProperty(type=cls, name="PHRT", description="PHRT ray tracing candidate settings")

    @classmethod
    def unregister(cls):
        del bpy.types.Object.phrt


class PHRT_MaterialSettings(bpy.types.PropertyGroup):
    """Material-slot element tags (Material.phrt): each object using a tagged
    material contributes one element made of that material's faces."""

    __annotations__ = _element_fields("material")

    @classmethod
    def register(cls):
        bpy.types.Material.phrt = PointerProperty(type=cls, name="PHRT", description="PHRT ray tracing candidate settings")

    @classmethod
    def unregister(cls):
        del bpy.types.Material.phrt


class PHRT_SceneSettings(bpy.types.PropertyGroup):
    """Scene-wide settings of the hybrid renderer (Scene.phrt)."""

    mode: EnumProperty(
        name="Mode",
        description="How PHRT renders the frame",
        items=_enum_items(schema.MODE_ITEMS),
        default="HYBRID",
    )
    budget_ms: FloatProperty(
        name="Frame Budget",
        description="Frame time target in milliseconds; the heuristic fits ray tracing into what raster leaves",
        default=defaults.BUDGET_MS, min=0.0, soft_max=1000.0,
    )
    use_budget_at: BoolProperty(
        name="Budget Between Modes",
        description="Give the budget as a fraction of the way from this machine's raster to its ray traced "
                    "frame time (Budget At) instead of milliseconds; replays resolve it from a short "
                    "calibration or from earlier runs of the path",
        default=False,
    )
    budget_at: FloatProperty(
        name="Budget At",
        description="Frame budget as a fraction of the way from raster (0) to ray traced (1) frame time "
                    "on this machine",
        default=defaults.BUDGET_AT, min=0.0, max=1.0, subtype="FACTOR",
    )
    selection: EnumProperty(
        name="Selection",
        description="How the hybrid frame chooses what to ray trace: the paper's heuristic, or (element, "
                    "effect) items bought for the most error removed per millisecond",
        items=_enum_items(schema.SELECTION_ITEMS),
        default="PAPER",
    )
    quality_tiers: BoolProperty(
        name="Quality Tiers",
        description="With the Benefit selection, an effect may be ray traced at half or quarter of its pixels "
                    "and the rest reconstructed from its neighbours (edge-aware), when that buys more within "
                    "the frame's time than tracing it fully or not at all",
        default=False,
    )
    relevance: EnumProperty(
        name="Relevance",
        description="What the heuristic's relevance R weighs: the paper's visibility, or visibility times "
                    "how much tracing the element changes its pixels",
        items=_enum_items(schema.RELEVANCE_ITEMS),
        default="PAPER",
    )
    selection_order: EnumProperty(
        name="Greedy Order",
        description="Order in which the selection pass takes elements that fit the time left",
        items=_enum_items(schema.ORDER_ITEMS),
        default="RELEVANCE",
    )
    selection_weight: FloatProperty(
        name="Selection Weight (I)",
        description="The paper's I: relevance bonus of an element selected last frame, which keeps elements "
                    "from flickering between raster and ray tracing",
        default=defaults.SELECTION_WEIGHT, min=0.0, soft_max=10.0,
    )
    max_area_fraction: FloatProperty(
        name="Max Area",
        description="Elements covering more than this fraction of the frame are never ray traced",
        default=defaults.MAX_AREA_FRACTION, min=0.0, max=1.0, subtype="FACTOR",
    )
    max_bounces: IntProperty(
        name="Max Bounces",
        description="Reflection and refraction rays traced one after another from a ray traced surface: "
                    "0 traces none (the raster look, traced shadows only), 1 one bounce (a mirror shows what "
                    "it faces, glass bends once and light then goes straight on), and so on",
        default=defaults.MAX_BOUNCES, min=0, max=64, soft_max=16,
    )
    cost_mode: EnumProperty(
        name="Cost Model",
        description="How the heuristic turns an element's cost into predicted milliseconds",
        items=_enum_items(schema.COST_MODE_ITEMS),
        default="MEASURED",
    )
    shadow_map_size: IntProperty(
        name="Shadow Map Size",
        description="Resolution in pixels of the raster shadow maps",
        default=defaults.SHADOW_MAP_SIZE, min=128, max=8192,
    )

    @classmethod
    def register(cls):
        bpy.types.Scene.phrt = PointerProperty(type=cls, name="PHRT", description="PHRT render settings")

    @classmethod
    def unregister(cls):
        del bpy.types.Scene.phrt


class PHRT_ReplaySettings(bpy.types.PropertyGroup):
    """What the Replay panel passes to phrt.replay_path (saved with the scene)."""

    camera: PointerProperty(
        name="Camera Path", type=bpy.types.Object, poll=lambda self, obj: obj.type == "CAMERA",
        description="The animated camera to replay; empty: the scene's first path")
    use_path_range: BoolProperty(
        name="Whole Path", default=True,
        description="Replay the camera's whole animation (its keyframe range); off: the frames below")
    frame_start: IntProperty(name="Start", default=1, min=0, description="First frame to render")
    frame_end: IntProperty(name="End", default=250, min=0, description="Last frame to render")
    modes: EnumProperty(name="Modes", items=MODE_FLAG_ITEMS, options={"ENUM_FLAG"}, default={"HYBRID"},
                        description="Render the path once in each chosen mode, each into its own run folder")
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", default="//phrt_runs", options=BLEND_RELATIVE_PATH,
                               description="Run folders <scene>-<path>-<mode> are written here "
                                           "('//' is the .blend file's folder)")
    images: EnumProperty(name="Images", items=IMAGE_ITEMS, default="EXR",
                         description="Image format of the rendered frames")


class PHRT_CandidateItem(bpy.types.PropertyGroup):
    """One element of the candidate list (a copy: edit the object's or material's settings)."""

    object_name: StringProperty(name="Object", description="The object this element belongs to")
    material_name: StringProperty(name="Material", description="The tagged material, for a material element")
    candidate: BoolProperty(name="Candidate", description="Tagged as a ray tracing candidate")
    priority: FloatProperty(name="Priority (K)", description="The paper's K at the last refresh")
    effects: StringProperty(name="Effects", description="Ray traced effects: Shd shadows, Rfl reflections, "
                                                        "Rfr refractions")
    rendered: BoolProperty(name="Rendered", description="The last rendered frame has a row for this element")
    visible: BoolProperty(name="Visible", description="Visible in the last rendered frame")
    visibility: FloatProperty(name="Visibility (V)", description="The paper's V in the last rendered frame")
    cost: FloatProperty(name="Cost (C)", description="The paper's C in the last rendered frame")
    relevance: FloatProperty(name="Relevance (R)", description="The paper's R in the last rendered frame "
                                                               "(-1 when not rendered)")
    selected: BoolProperty(name="Ray Traced", description="Ray traced in the last rendered frame")
    reason: StringProperty(name="Reason", description="Why it was not ray traced: not_visible, over_area, "
                                                      "over_budget or not_candidate")


def _redraw_3d_views(window_manager, context):
    for area in context.screen.areas if context.screen else ():
        if area.type == "VIEW_3D":
            area.tag_redraw()


CLASSES = (PHRT_ObjectSettings, PHRT_MaterialSettings, PHRT_SceneSettings, PHRT_ReplaySettings, PHRT_CandidateItem)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Scene.phrt_replay = PointerProperty(type=PHRT_ReplaySettings, name="PHRT Replay",
                                                  description="Settings of the Replay panel")
    bpy.types.WindowManager.phrt_candidates = CollectionProperty(type=PHRT_CandidateItem)
    bpy.types.WindowManager.phrt_candidate_index = IntProperty(
        name="Active Element", default=-1, update=candidate_list.select_element,
        description="Clicking an element selects its object")
    bpy.types.WindowManager.phrt_overlay = BoolProperty(
        name="Decision Overlay", default=False, update=_redraw_3d_views,
        description="Box every candidate in the 3D view, coloured by the last rendered frame's decision")


def unregister():
    del bpy.types.WindowManager.phrt_overlay
    del bpy.types.WindowManager.phrt_candidate_index
    del bpy.types.WindowManager.phrt_candidates
    del bpy.types.Scene.phrt_replay
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
