"""The N panel's candidate list: every element of the scene with its settings and, from
the last rendered frame (``engine.final.LAST_FRAME['rows']``), its visibility V, cost C,
relevance R and whether it was ray traced or why not.

A ``UIList`` needs a collection to show: ``WindowManager.phrt_candidates`` (not saved
with the file: it mirrors the scene and the last frame).  It is rebuilt by
``refresh()`` - from the ``phrt.refresh_candidates`` operator, after a replay, and
after every render (a ``render_post`` handler; renders started with F12 finish on
the render thread, so those refreshes are handed to the main thread through a
queue that a timer drains).  Clicking an element selects its object.
"""

import queue
import threading

import bpy
from bpy.props import BoolProperty, CollectionProperty, FloatProperty, IntProperty, StringProperty

from ..engine import extract, final
from ..phrt_addon import naming

# What the list says about an element's last decision: reason -> (text, icon).
DECISIONS = {
    "selected": ("Ray traced", "CHECKMARK"),
    "over_budget": ("Over budget", "TIME"),
    "over_area": ("Over area", "FULLSCREEN_ENTER"),
    "not_visible": ("Not visible", "HIDE_ON"),
    "not_candidate": ("Not a candidate", "BLANK1"),
    "": ("Not rendered yet", "QUESTION"),
}
EFFECT_LABELS = (("shadows", "Shd"), ("reflections", "Rfl"), ("refractions", "Rfr"))


def effects_text(settings) -> str:
    """``'Shd Rfl'``: the ray traced effects an element gets (``-`` for none)."""
    return " ".join(label for name, label in EFFECT_LABELS if getattr(settings, name)) or "-"


def decision_key(rendered, selected, reason) -> str:
    """The key of DECISIONS for an element's last frame."""
    if not rendered:
        return ""
    return "selected" if selected else (reason if reason in DECISIONS else "")


def live_settings(item):
    """The Object.phrt or Material.phrt an entry was listed from (None once it is deleted),
    so the list shows K and effects as they are now, not as at the last refresh."""
    if item.material_name:
        owner = bpy.data.materials.get(item.material_name)
    else:
        owner = bpy.data.objects.get(item.object_name)
    return owner.phrt if owner is not None else None


def _settings_entry(name, object_name, material_name, settings, candidate):
    return {"name": name, "object_name": object_name, "material_name": material_name or "",
            "candidate": bool(candidate), "priority": float(settings.priority), "effects": effects_text(settings),
            "rendered": False, "visible": False, "visibility": 0.0, "cost": 0.0, "relevance": -1.0,
            "selected": False, "reason": ""}


def candidate_entries(scene, rows) -> list:
    """One dict per element: the scene's objects (as ``extract`` names them: ``Obj`` and,
    for each tagged material, ``Obj/Material``) merged with the last frame's ``rows``;
    elements only the frame knows (instances ``Obj@Parent:id``) come after, when their
    object exists."""
    entries = {}
    for obj in sorted(scene.objects, key=lambda o: o.name):
        if obj.type not in extract.MESH_CONVERTIBLE or obj.hide_render:
            continue
        materials = [slot.material for slot in obj.material_slots]
        tagged = []
        for material in materials:
            if material is not None and material.phrt.candidate and material not in tagged:
                tagged.append(material)
        for material in tagged:
            name = naming.material_element(obj.name, material.name)
            entries[name] = _settings_entry(name, obj.name, material.name, material.phrt, True)
        if not materials or any(m is None or not m.phrt.candidate for m in materials):
            entries[obj.name] = _settings_entry(obj.name, obj.name, "", obj.phrt, obj.phrt.candidate)
    objects = bpy.data.objects
    for row in rows:
        name = str(row["element"])
        entry = entries.get(name)
        if entry is None:
            object_name = naming.element_object_name(name, objects)
            if object_name is None:
                continue  # a frame of another file
            owner = objects[object_name].phrt
            entry = entries[name] = _settings_entry(name, object_name, "", owner, row.get("reason") != "not_candidate")
            entry["priority"] = float(row.get("K") or 0.0)
        entry.update(rendered=True, visible=bool(row.get("visible")), selected=bool(row.get("selected")),
                     reason=str(row.get("reason") or ""), visibility=float(row.get("V") or 0.0),
                     cost=float(row.get("C") or 0.0), relevance=float(row.get("R") or 0.0))
    return list(entries.values())


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


_REFRESHING = False


def _select_element(window_manager, context):
    """Clicking an element in the list selects (and activates) its object."""
    if _REFRESHING:
        return
    items = window_manager.phrt_candidates
    index = window_manager.phrt_candidate_index
    if not 0 <= index < len(items):
        return
    item = items[index]
    obj = bpy.data.objects.get(item.object_name)
    view_layer = context.view_layer
    if obj is None or view_layer is None or view_layer.objects.get(obj.name) is None:
        return
    for other in context.selected_objects:
        other.select_set(False)
    obj.select_set(True)
    view_layer.objects.active = obj
    if item.material_name:
        for slot_index, slot in enumerate(obj.material_slots):
            if slot.material is not None and slot.material.name == item.material_name:
                obj.active_material_index = slot_index
                break


def refresh(window_manager, scene) -> int:
    """Rebuild ``window_manager.phrt_candidates`` for ``scene``; returns the element count."""
    global _REFRESHING
    items = window_manager.phrt_candidates
    index = window_manager.phrt_candidate_index
    active = items[index].name if 0 <= index < len(items) else None
    entries = candidate_entries(scene, final.LAST_FRAME["rows"])
    _REFRESHING = True
    try:
        items.clear()
        for entry in entries:
            item = items.add()
            for key, value in entry.items():
                setattr(item, key, value)
        names = [entry["name"] for entry in entries]
        window_manager.phrt_candidate_index = names.index(active) if active in names else -1
    finally:
        _REFRESHING = False
    return len(entries)


class PHRT_UL_candidates(bpy.types.UIList):
    """Elements with K, their last decision and R; sortable by R, filterable by name."""

    sort_by_relevance: BoolProperty(name="Sort by R", default=True,
                                    description="Most relevant first (the paper's R of the last rendered frame)")
    show_non_candidates: BoolProperty(name="Show Non-Candidates", default=False,
                                      description="Also list the elements that are not tagged as candidates")

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0, flt_flag=0):
        status_icon = DECISIONS[decision_key(item.rendered, item.selected, item.reason)][1]
        row = layout.row(align=True)
        row.label(text=item.name, icon=status_icon)
        values = row.row(align=True)
        values.alignment = "RIGHT"
        settings = live_settings(item)
        values.label(text=f"K {settings.priority if settings is not None else item.priority:.3g}")
        values.label(text=f"R {item.relevance:.3g}" if item.rendered else "R -")

    def draw_filter(self, context, layout):
        row = layout.row(align=True)
        row.prop(self, "filter_name", text="")
        row.prop(self, "use_filter_invert", text="", icon="ARROW_LEFTRIGHT")
        row = layout.row(align=True)
        row.prop(self, "sort_by_relevance", toggle=True)
        row.prop(self, "use_filter_sort_reverse", text="", icon="SORT_DESC")
        row.prop(self, "show_non_candidates", toggle=True)

    def filter_items(self, context, data, propname):
        items = getattr(data, propname)
        if self.filter_name:
            flags = bpy.types.UI_UL_list.filter_items_by_name(self.filter_name, self.bitflag_filter_item, items,
                                                              "name", reverse=False)
        else:
            flags = [self.bitflag_filter_item] * len(items)
        if not self.show_non_candidates:
            flags = [flag if item.candidate else 0 for flag, item in zip(flags, items)]
        order = []
        if self.sort_by_relevance:
            order = relevance_order([item.relevance if item.rendered else None for item in items])
        return flags, order


def relevance_order(relevances) -> list:
    """A UIList ``flt_neworder`` (original index -> shown position) putting the highest R
    first and elements without R (``None``) last, in their original order."""
    ranked = sorted(range(len(relevances)),
                    key=lambda i: (relevances[i] is None, -(relevances[i] or 0.0), i))
    order = [0] * len(relevances)
    for position, original in enumerate(ranked):
        order[original] = position
    return order


# -- refreshing after renders ------------------------------------------------------
_PENDING = queue.SimpleQueue()  # names of scenes whose list waits for the main thread
_DRAIN_SECONDS = 0.5


def _refresh_scene(scene_name):
    scene = bpy.data.scenes.get(scene_name)
    if scene is not None and bpy.data.window_managers:
        refresh(bpy.data.window_managers[0], scene)


@bpy.app.handlers.persistent
def refresh_after_render(scene, *args):
    """render_post: refresh now on the main thread (scripts, background), else queue."""
    if threading.current_thread() is threading.main_thread():
        _refresh_scene(scene.name)
    else:
        _PENDING.put(scene.name)


def _drain_pending():
    names = set()
    while True:
        try:
            names.add(_PENDING.get_nowait())
        except queue.Empty:
            break
    for name in names:
        _refresh_scene(name)
    return _DRAIN_SECONDS


CLASSES = (PHRT_CandidateItem, PHRT_UL_candidates)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.WindowManager.phrt_candidates = CollectionProperty(type=PHRT_CandidateItem)
    bpy.types.WindowManager.phrt_candidate_index = IntProperty(
        name="Active Element", default=-1, update=_select_element,
        description="Clicking an element selects its object")
    bpy.app.handlers.render_post.append(refresh_after_render)
    if not bpy.app.background:
        bpy.app.timers.register(_drain_pending, first_interval=_DRAIN_SECONDS, persistent=True)


def unregister():
    if bpy.app.timers.is_registered(_drain_pending):
        bpy.app.timers.unregister(_drain_pending)
    while refresh_after_render in bpy.app.handlers.render_post:
        bpy.app.handlers.render_post.remove(refresh_after_render)
    del bpy.types.WindowManager.phrt_candidate_index
    del bpy.types.WindowManager.phrt_candidates
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
