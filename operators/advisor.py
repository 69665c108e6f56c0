"""The Advisor: ``phrt.advise_path`` measures what each tag is worth along the active camera's
path (``engine/runs/advise.py``), ``phrt.apply_advice`` applies one recommendation.

- ``phrt.advise_path``: in the UI a modal operator (one render or so per timer tick, progress in
  the cursor counter and the status bar, Esc cancels and restores the scene); from a script
  (execute) the same steps to the end.  The items land in ``WindowManager.phrt_advice`` (the N
  panel's list) and the files in the output folder (docs/advice.md).
- ``phrt.apply_advice``: the chosen item's recommendation turned into property changes of its
  owner (``Object.phrt`` or ``Material.phrt``: tag, untag, an effect off, K up or down) by
  ``phrt_addon/advise/recommend.changes``, all in one operator call: one undo step.
"""
from pathlib import Path

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

from ..engine.runs import advise, item_measure
from ..engine.runs import camera_path
from ..phrt_addon.advise import items as advice_items
from ..phrt_addon.advise import recommend
from . import replay_path

# Events a running advice lets through, so the designer can still look around.
NAVIGATION_EVENTS = {"MIDDLEMOUSE", "WHEELUPMOUSE", "WHEELDOWNMOUSE", "TRACKPADPAN", "TRACKPADZOOM", "MOUSEMOVE",
                     "INBETWEEN_MOUSEMOVE", "NDOF_MOTION"}
ICONS = {"keep": "CHECKMARK", "untag": "X", "drop_effect": "REMOVE", "raise_priority": "SORT_DESC",
         "lower_priority": "SORT_ASC", "tag": "ADD"}


class PHRT_AdviceItem(bpy.types.PropertyGroup):
    """One (element, effect) item of the last advice."""

    element: StringProperty(name="Element")
    effect: StringProperty(name="Effect")
    tagged: BoolProperty(name="Tagged")
    recommendation: StringProperty(name="Recommendation")
    reason: StringProperty(name="Reason")
    benefit_per_ms: FloatProperty(name="Benefit per ms", description="Mean LDR-FLIP removed per ms of tracing")
    applied: BoolProperty(name="Applied", description="This recommendation was applied")


def parse_budgets(text) -> tuple:
    """'0.25,0.5' -> (0.25, 0.5); ValueError with what is wrong."""
    values = []
    for part in str(text).split(","):
        part = part.strip()
        if not part:
            continue
        value = float(part)
        if not 0.0 <= value <= 1.0:
            raise ValueError(f"budget {value:g} is outside 0..1 (0 = raster, 1 = ray traced frame time)")
        values.append(value)
    if not values:
        raise ValueError("give at least one budget, e.g. 0.25,0.5,0.75")
    return tuple(values)


def fill_list(window_manager, csv_path):
    """The N panel's advice list from an ``advice.csv``."""
    import csv
    collection = window_manager.phrt_advice
    collection.clear()
    with open(csv_path, newline="", encoding="utf-8") as handle:
        for row in csv.DictReader(handle):
            item = collection.add()
            item.element, item.effect, item.tagged = row["element"], row["effect"], row["tagged"] == "1"
            item.recommendation, item.reason = row["recommendation"], row["reason"]
            item.benefit_per_ms = float(row["benefit_per_ms"] or 0.0)
    window_manager.phrt_advice_index = 0 if len(collection) else -1


class PHRT_OT_advise_path(bpy.types.Operator):
    """Measure what each tag (and each untagged glossy, metallic or glass object) is worth per millisecond
    along the active camera's path, and recommend keep, untag, drop an effect, change K or tag"""

    bl_idname = "phrt.advise_path"
    bl_label = "Advise Tags"

    frame_start: IntProperty(name="Start", default=0, description="First frame (0: the path's first)")
    frame_end: IntProperty(name="End", default=0, description="Last frame (0: the path's last)")
    budget_at: StringProperty(name="Budgets", default="0.25,0.5,0.75",
                              description="Budgets as fractions of the way from raster (0) to ray traced (1) frame "
                                          "time, comma separated")
    every: IntProperty(name="Judge Every", default=advise.DEFAULT_EVERY, min=1,
                       description="Judge every N-th frame (each judged frame traces every item alone)")
    output_dir: StringProperty(name="Output", default="//phrt_advice", subtype="DIR_PATH",
                               description="Folder for advice.csv/json/md/html ('//' is the .blend file's folder)")

    @classmethod
    def poll(cls, context):
        return context.scene is not None and context.scene.camera is not None

    def _steps(self, context):
        scene = context.scene
        camera = scene.camera
        start, end = camera_path.path_frame_range(scene, camera)
        if self.frame_start > 0:
            start = self.frame_start
        if self.frame_end > 0:
            end = self.frame_end
        camera_path.check_frame_range(start, end)
        budgets = parse_budgets(self.budget_at)
        root = replay_path.output_root(self.output_dir)
        replay_path.check_output_root(root)
        self._out = Path(root) / f"{replay_path.scene_label(scene)}-{camera.name}-advice"
        return advise.advice_steps(scene, camera, (start, end), self._out, budget_at=budgets, every=self.every,
                                   scene_label=replay_path.scene_label(scene),
                                   should_stop=lambda: self._stop_asked)

    def _done(self, context, written):
        fill_list(context.window_manager, written["csv"])
        context.window_manager.phrt_advice_folder = str(self._out)
        self.report({"INFO"}, f"PHRT: advice written to {self._out}")

    def execute(self, context):
        self._stop_asked = False
        try:
            steps = self._steps(context)
            for step in steps:
                if step[0] == "done":
                    self._done(context, step[1])
        except (ValueError, camera_path.ReplayError) as error:
            self.report({"ERROR"}, f"PHRT: {error}")
            return {"CANCELLED"}
        return {"FINISHED"}

    def invoke(self, context, event):
        self._stop_asked = False
        try:
            self._generator = self._steps(context)
        except (ValueError, camera_path.ReplayError) as error:
            self.report({"ERROR"}, f"PHRT: {error}")
            return {"CANCELLED"}
        window_manager = context.window_manager
        window_manager.progress_begin(0, 100)
        self._timer = window_manager.event_timer_add(0.01, window=context.window)
        window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self._stop_asked = True
        if event.type != "TIMER":
            return {"PASS_THROUGH"} if event.type in NAVIGATION_EVENTS else {"RUNNING_MODAL"}
        try:
            step = next(self._generator)
        except advise.AdviceCancelled:
            self._cleanup(context, "PHRT: advice cancelled; the scene is as it was")
            return {"CANCELLED"}
        except (ValueError, camera_path.ReplayError, RuntimeError) as error:
            self._cleanup(context, f"PHRT: advice failed: {error}")
            return {"CANCELLED"}
        if step[0] == "done":
            self._done(context, step[1])
            self._cleanup(context, None)
            return {"FINISHED"}
        done, total, what = step
        context.window_manager.progress_update(int(100 * done / max(total, 1)))
        context.workspace.status_text_set(f"PHRT Advisor: {what} ({done}/{total}), Esc to cancel")
        return {"RUNNING_MODAL"}

    def cancel(self, context):
        self._generator.close()
        self._cleanup(context, None)

    def _cleanup(self, context, message):
        window_manager = context.window_manager
        if getattr(self, "_timer", None) is not None:
            window_manager.event_timer_remove(self._timer)
            self._timer = None
        window_manager.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        if message:
            self.report({"WARNING"}, message)


def apply_item(window_manager, index) -> dict:
    """Apply the recommendation of advice item ``index``; returns {property: new value} set."""
    collection = window_manager.phrt_advice
    item = collection[index]
    owner = item_measure.owner_of(item.element)
    if owner is None:
        raise ValueError(f"'{item.element}' is no longer in the scene")
    tag_effects = [other.effect for other in collection
                   if other.element == item.element and other.recommendation == "tag"]
    changed = recommend.changes(item.element, item.effect, item.recommendation,
                                item_measure.read_settings(owner), tag_effects)
    for name, value in changed.items():
        setattr(owner.phrt, name, value)
    for other in collection:
        if other.element == item.element and (other.effect == item.effect or
                                              (item.recommendation == "tag" and other.recommendation == "tag")):
            other.applied = True
    return changed


class PHRT_OT_apply_advice(bpy.types.Operator):
    """Apply the chosen item's recommendation to its object or material (one undo step)"""

    bl_idname = "phrt.apply_advice"
    bl_label = "Apply Recommendation"
    bl_options = {"REGISTER", "UNDO"}

    index: IntProperty(name="Item", default=-1, description="Advice item (-1: the one selected in the list)")

    @classmethod
    def poll(cls, context):
        return len(context.window_manager.phrt_advice) > 0

    def execute(self, context):
        window_manager = context.window_manager
        index = self.index if self.index >= 0 else window_manager.phrt_advice_index
        if not 0 <= index < len(window_manager.phrt_advice):
            self.report({"ERROR"}, "PHRT: choose an advice item first")
            return {"CANCELLED"}
        try:
            changed = apply_item(window_manager, index)
        except ValueError as error:
            self.report({"ERROR"}, f"PHRT: {error}")
            return {"CANCELLED"}
        item = window_manager.phrt_advice[index]
        what = ", ".join(f"{name} = {value:g}" if isinstance(value, float) else f"{name} = {value}"
                         for name, value in changed.items()) or "nothing to change"
        self.report({"INFO"}, f"PHRT: {advice_items.item_key(item.element, item.effect)}: {what}")
        return {"FINISHED"}


CLASSES = (PHRT_AdviceItem, PHRT_OT_advise_path, PHRT_OT_apply_advice)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    window_manager = bpy.types.WindowManager
    window_manager.phrt_advice = bpy.props.CollectionProperty(type=PHRT_AdviceItem)
    window_manager.phrt_advice_index = IntProperty(name="Advice Item", default=-1)
    window_manager.phrt_advice_folder = StringProperty(name="Advice Folder", subtype="DIR_PATH")


def unregister():
    for name in ("phrt_advice_folder", "phrt_advice_index", "phrt_advice"):
        if hasattr(bpy.types.WindowManager, name):
            delattr(bpy.types.WindowManager, name)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
