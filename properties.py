"""Blender properties of PHRT: what designers tag on objects and materials, and
the scene-wide settings of the hybrid renderer (CONTRACT.md section 3).

Each PropertyGroup attaches itself in its ``register()`` classmethod and
detaches in ``unregister()``.
"""
import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

from .phrt_addon import defaults, schema


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
        from .panels import candidates
        candidates.refresh(window_manager, scene)


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
            description="The paper's Q: a multiplier on the engine's own measured ray tracing cost of this element",
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


CLASSES = (PHRT_ObjectSettings, PHRT_MaterialSettings, PHRT_SceneSettings)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
