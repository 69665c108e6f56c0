"""The candidate list's content: every element of the scene (as ``extract`` names them,
``phrt_addon/naming.py``) with its settings, merged with the last rendered frame's
decisions (``session.last_frame().rows``): visibility V, cost C, relevance R, whether it
was ray traced or why not.

It fills ``WindowManager.phrt_candidates`` (``properties.py``), which the N panel's
``UIList`` shows (``panels/candidates.py``).  ``refresh()`` rebuilds it - from the
``phrt.refresh_candidates`` operator, after a replay, when a tag changes, and after every
render (a ``render_post`` handler; renders started with F12 finish on the render thread,
so those refreshes are handed to the main thread through the session's queue, which a
timer drains).  Clicking an element selects its object (``select_element``).
"""
import queue
import threading

import bpy

from ..phrt_addon import naming
from . import extract, session

DRAIN_SECONDS = 0.5

EFFECT_LABELS = (("shadows", "Shd"), ("reflections", "Rfl"), ("refractions", "Rfr"))


def effects_text(settings) -> str:
    """``'Shd Rfl'``: the ray traced effects an element gets (``-`` for none)."""
    return " ".join(label for name, label in EFFECT_LABELS if getattr(settings, name)) or "-"


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
            name = naming.object_element(obj.name)
            entries[name] = _settings_entry(name, obj.name, "", obj.phrt, obj.phrt.candidate)
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


def select_element(window_manager, context):
    """Clicking an element in the list selects (and activates) its object."""
    if session.current().refreshing_candidates:
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
    items = window_manager.phrt_candidates
    index = window_manager.phrt_candidate_index
    active = items[index].name if 0 <= index < len(items) else None
    entries = candidate_entries(scene, session.last_frame().rows)
    engine_session = session.current()
    engine_session.refreshing_candidates = True
    try:
        items.clear()
        for entry in entries:
            item = items.add()
            for key, value in entry.items():
                setattr(item, key, value)
        names = [entry["name"] for entry in entries]
        window_manager.phrt_candidate_index = names.index(active) if active in names else -1
    finally:
        engine_session.refreshing_candidates = False
    return len(entries)


# -- refreshing after renders ------------------------------------------------------


def refresh_scene(scene_name):
    scene = bpy.data.scenes.get(scene_name)
    if scene is not None and bpy.data.window_managers:
        refresh(bpy.data.window_managers[0], scene)


@bpy.app.handlers.persistent
def refresh_after_render(scene, *args):
    """render_post: refresh now on the main thread (scripts, background), else queue."""
    if threading.current_thread() is threading.main_thread():
        refresh_scene(scene.name)
    else:
        session.current().pending_refresh.put(scene.name)


def drain_pending():
    names = set()
    while True:
        try:
            names.add(session.current().pending_refresh.get_nowait())
        except queue.Empty:
            break
    for name in names:
        refresh_scene(name)
    return DRAIN_SECONDS
