"""The N panel's candidate list: the ``UIList`` showing ``WindowManager.phrt_candidates``
(filled by ``engine/candidate_list.py``: every element with its settings and the last
frame's V, C, R and decision), and the handlers that keep it fresh after renders.
"""

import bpy
from bpy.props import BoolProperty

from ..engine import candidate_list

# What the list says about an element's last decision: reason -> (text, icon).
DECISIONS = {
    "selected": ("Ray traced", "CHECKMARK"),
    "over_budget": ("Over budget", "TIME"),
    "over_area": ("Over area", "FULLSCREEN_ENTER"),
    "not_visible": ("Not visible", "HIDE_ON"),
    "not_candidate": ("Not a candidate", "BLANK1"),
    "": ("Not rendered yet", "QUESTION"),
}


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


CLASSES = (PHRT_UL_candidates,)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.app.handlers.render_post.append(candidate_list.refresh_after_render)
    if not bpy.app.background:
        bpy.app.timers.register(candidate_list.drain_pending, first_interval=candidate_list.DRAIN_SECONDS,
                                persistent=True)


def unregister():
    if bpy.app.timers.is_registered(candidate_list.drain_pending):
        bpy.app.timers.unregister(candidate_list.drain_pending)
    while candidate_list.refresh_after_render in bpy.app.handlers.render_post:
        bpy.app.handlers.render_post.remove(candidate_list.refresh_after_render)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
