"""What the trace stage (``stage.TraceStage``) returns: the traced terms, the counters the cost
model learns from (rays and ms per effect, one-time work apart) and the rays per element and
item; and which effects of which elements a selection traces."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..frame_types import TracedTerms

EFFECTS = ("shadows", "reflections", "refractions")


def traced_effects(elements, selected, effects=None) -> dict[str, np.ndarray]:
    """Per effect, the elements whose effect is traced: selected, tagged for it, and (when
    ``effects`` names the effect) chosen for it."""
    selected = np.asarray(selected, bool)
    wanted = {}
    for effect in EFFECTS:
        tagged = np.fromiter((bool(getattr(element, effect)) for element in elements), bool, len(elements))
        chosen = selected & tagged
        if effects is not None and effect in effects:
            chosen &= np.asarray(effects[effect], bool)
        wanted[effect] = chosen
    return wanted


@dataclass
class TraceCounters:
    """Rays cast and ms spent per effect; ``upload_ms``: a static Embree build (one-time work)."""

    shadow_rays: int = 0
    reflection_rays: int = 0
    refraction_rays: int = 0
    shadow_ms: float = 0.0
    reflection_ms: float = 0.0
    refraction_ms: float = 0.0
    upload_ms: float = 0.0
    # Of shadow_ms, building the lights' shadow regions over the frame's pixels: a fixed part of
    # any frame that traces shadows, whatever the casters' sizes (select/item_costs.py).
    shadow_setup_ms: float = 0.0
    # Of each effect's ms, the time inside Embree's queries (its per-ray part, numpy aside).
    shadow_embree_ms: float = 0.0
    reflection_embree_ms: float = 0.0
    refraction_embree_ms: float = 0.0
    # Per effect name, of its ms the edge-aware reconstruction of pixels not cast at a reduced
    # rate, and how many pixels it filled (its cost per pixel: select/item_costs.py).
    reconstruct_ms: dict = field(default_factory=dict)
    reconstructed_px: dict = field(default_factory=dict)

    @property
    def rays(self):
        return self.shadow_rays + self.reflection_rays + self.refraction_rays


@dataclass
class TraceResult:
    traced: TracedTerms
    counters: TraceCounters = field(default_factory=TraceCounters)
    # (n_elements,) rays cast for each element, in the units of the counters: every ray of an effect
    # (a bounce's hit shadow rays and further bounces included) goes to the elements whose pixels
    # cast it, shared in proportion where casters' shadow regions overlap; summed, the counters' rays.
    element_rays: np.ndarray = None
    # (n_elements, 3) the same rays split by effect (EFFECTS order): what each item cast.
    item_rays: np.ndarray = None
    # (h, w) float32, the ``PHRT Rate`` debug pass: per pixel the highest rate of any effect (either
    # layer) whose traced or reconstructed value replaced the raster term there, 0 elsewhere
    # (row 0 at the bottom); ``effect_rate``: the same per effect name.
    rate: np.ndarray | None = None
    effect_rate: dict = field(default_factory=dict)
