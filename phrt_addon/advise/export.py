"""The designer's tags with their measured value, for a game engine (docs/advice.md).

One entry per element that is tagged or was judged: its PHRT tag (candidate, K, effects, Q), per
effect the measured benefit per ms and the recommendation, and two engine-neutral knobs:

- ``culling_priority`` 0-8, Unreal-style (``RayTracingGroupCullingPriority``: 0 never cull ...
  8 cull quickly): ``round(log2(best / own))`` of the element's benefit per ms against the best
  element's of the level, so each halving of value per ms is one step; an element worth
  nothing (every effect below the noise floor or advised off) is 8;
- ``visible_in_ray_tracing``: whether the object should be in the ray tracing scene at all
  (Unreal's per-primitive "Visible in Ray Tracing", Unity HDRP's Ray Tracing Mode Off): false
  when no effect of it is worth keeping or tagging.

Plain Python.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

FORMAT = "phrt-tags"
VERSION = 1
MAX_CULLING_PRIORITY = 8
# Recommendations that leave an effect traced (after applying the advice).
TRACED = ("keep", "raise_priority", "lower_priority", "tag")


def culling_priority(benefit_per_ms: float, best_per_ms: float, worth: bool) -> int:
    """0 (never cull) for the best value per ms, one step per halving, 8 at 1/256 or when worthless."""
    if not worth or benefit_per_ms <= 0 or best_per_ms <= 0:
        return MAX_CULLING_PRIORITY
    return int(min(max(round(math.log2(best_per_ms / benefit_per_ms)), 0), MAX_CULLING_PRIORITY))


def export_tags(rows, settings_by_element: dict, scene: str, path: str) -> dict:
    """The export document from the advice rows (``files.advice_rows``) and each element's current
    settings ({element: {candidate, priority, rt_cost, shadows, reflections, refractions}})."""
    by_element = {}
    for row in rows:
        by_element.setdefault(row["element"], []).append(row)
    values = {}
    for element, items in by_element.items():
        kept = [row for row in items if row["recommendation"] in TRACED]
        cost = sum(row["cost_ms"] for row in kept)
        values[element] = (sum(max(row["benefit"], 0.0) for row in kept) / cost) if kept and cost > 0 else 0.0
    best = max(values.values(), default=0.0)
    elements = []
    for element in sorted(set(by_element) | set(settings_by_element)):
        items = by_element.get(element, [])
        settings = settings_by_element.get(element, {})
        worth = any(row["recommendation"] in TRACED for row in items)
        elements.append({
            "element": element, "tagged": bool(settings.get("candidate", False)),
            "priority_k": settings.get("priority"), "rt_cost_q": settings.get("rt_cost"),
            "effects": {row["effect"]: {"tagged": bool(row["tagged"]), "benefit_per_ms": row["benefit_per_ms"],
                                        "benefit": row["benefit"], "cost_ms": row["cost_ms"],
                                        "recommendation": row["recommendation"]} for row in items},
            "tagged_effects": [effect for effect in ("shadows", "reflections", "refractions") if settings.get(effect)],
            "benefit_per_ms": values.get(element, 0.0),
            "culling_priority": culling_priority(values.get(element, 0.0), best, worth),
            "visible_in_ray_tracing": worth if items else bool(settings.get("candidate", False)),
            "judged": bool(items)})
    return {"format": FORMAT, "version": VERSION, "scene": scene, "path": path, "elements": elements}


def write_export(path, document: dict) -> Path:
    path = Path(path)
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    os.replace(temporary, path)
    return path
