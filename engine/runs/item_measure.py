"""Tracing one item alone and measuring it: the oracle's measurement, for (element, effect) items.

:func:`measure_subset` renders a frame with a chosen set traced (``oracle.ForcedRenderer``),
``oracle.TIMINGS`` times, and returns the image, the median trace ms (without one-time Embree uploads),
the timings' spread, and its LDR-FLIP against the reference (mean, and per pixel when asked).
The oracle's "each candidate traced alone" and the advisor's "each item traced alone" are this
one function.

:class:`ItemScope` makes the scene say which effects each element has while measuring: untagged
objects (prospects) become temporary candidates for the effects being judged, and an item
(element, effect) is traced alone by giving its element only that effect for the render (the
designer's own switches, ``Object.phrt`` / ``Material.phrt``, which the trace stage honours).
Everything it changed is restored on exit.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ...phrt_addon import naming
from ...phrt_addon.report import metrics, oracle
from ...phrt_addon.schema import EFFECTS

FIELDS = ("candidate", "priority", "rt_cost") + EFFECTS


def trace_ms(stats) -> float:
    """The trace stage's measured ms without one-time Embree uploads."""
    return max(float(stats["trace_ms"]) - float(stats.get("upload_ms") or 0.0), 0.0)


@dataclass
class Measured:
    image: np.ndarray
    trace_ms: float  # median of the timings
    spread_ms: float  # max - min of the timings
    flip: float | None  # mean LDR-FLIP against the reference (None without one)
    flip_map: np.ndarray | None  # per-pixel LDR-FLIP (when asked)
    stats: dict
    selection: object


def measure_subset(renderer, frame, names, reference=None, *, timings=oracle.TIMINGS, per_pixel=False,
                   rates=None) -> Measured:
    """Render ``frame`` with ``names`` traced ``timings`` times (the oracle's ``TIMINGS``: one timing
    hands the measurement the luckiest of them, a winner's curse; the images are the same: the first
    is kept) and measure it against ``reference`` (linear RGB, top row first): the median and spread
    of the timings (``oracle.median_ms``) and the LDR-FLIP.  ``rates``: the forced rates
    (``ForcedRenderer.render``; None: full rate)."""
    image, stats, selection = renderer.render(frame, names, rates)
    measured = [trace_ms(stats)]
    for _ in range(max(int(timings), 1) - 1):
        measured.append(trace_ms(renderer.render(frame, names, rates)[1]))
    error = error_map = None
    if reference is not None:
        error = metrics.flip(reference, image)
        if per_pixel:
            error_map = metrics.flip_map(reference, image)
    median, spread = oracle.median_ms(measured)
    return Measured(image=image, trace_ms=median, spread_ms=spread, flip=error, flip_map=error_map, stats=stats, selection=selection)


def owner_of(element: str):
    """The Object or Material whose ``phrt`` settings make ``element`` (None when gone)."""
    objects = bpy.data.objects
    name = naming.element_object_name(element, objects.keys())
    if name is None:
        return None
    base = naming.base_element(element)
    if element not in objects and base is not None:
        found = bpy.data.materials.get(element[len(base) + len(naming.MATERIAL_SEPARATOR):])
        if found is not None:
            return found
    return objects.get(name)


def read_settings(owner) -> dict:
    settings = owner.phrt
    return {field: getattr(settings, field) for field in FIELDS}


class ItemScope:
    """``with ItemScope(prospects) as scope:`` (``{element: effects}`` of untagged objects to judge);
    ``scope.trace_only({element: effects})`` before each render; everything restored on exit."""

    def __init__(self, prospects=None):
        self.prospects = {element: tuple(effects) for element, effects in (prospects or {}).items()}
        self._saved = {}
        self._judging = {}

    def __enter__(self):
        for element, effects in self.prospects.items():
            owner = owner_of(element)
            if owner is None:
                continue
            self._remember(owner)
            self._set(owner, {"candidate": True, **{effect: effect in effects for effect in EFFECTS}})
        self._judging = {key: dict(value) for key, value in self._current().items()}
        return self

    def __exit__(self, *exc):
        for owner, settings in self._saved.values():
            self._set(owner, settings)
        self._saved.clear()
        return False

    def _remember(self, owner):
        key = (type(owner).__name__, owner.name)
        if key not in self._saved:
            self._saved[key] = (owner, read_settings(owner))

    def _current(self):
        return {key: read_settings(owner) for key, (owner, _) in self._saved.items()}

    @staticmethod
    def _set(owner, values):
        settings = owner.phrt
        for field, value in values.items():
            if getattr(settings, field) != value:
                setattr(settings, field, value)

    def trace_only(self, effects_of: dict) -> list:
        """Give each element of ``effects_of`` ({element: effects}) only those effects, every other
        element changed so far back its judging state; returns the element names to force."""
        wanted = {}
        for element, effects in effects_of.items():
            owner = owner_of(element)
            if owner is None:
                continue
            self._remember(owner)
            key = (type(owner).__name__, owner.name)
            self._judging.setdefault(key, read_settings(owner))
            wanted[key] = (owner, {effect: effect in effects for effect in EFFECTS})
        for key, (owner, _) in self._saved.items():
            base = dict(self._judging.get(key, read_settings(owner)))
            if key in wanted:
                base.update(wanted[key][1])
            self._set(owner, base)
        return list(effects_of)
