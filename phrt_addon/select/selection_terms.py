"""The paper's terms of every element (equations 1-3), one frame at a time.

Area A, centre closeness P, distance D, visibility V, cost C and relevance R,
computed on whole arrays that the engine fills from its scene snapshot and its
G-buffer (:class:`FrameElements`, :func:`element_terms`); the settings of a
selection (:class:`SelectionSettings`).  ``heuristic.py`` selects from them.

Decisions where the paper is vague
----------------------------------
Visible
    An element is visible when it has at least one pixel in the G-buffer's
    element-id target (``area_px > 0``).  Hidden and off-screen elements alike
    are ``not_visible``.
A (area)
    ``area_px / frame_px``: the exact pixel count, in [0, 1].
P (centre closeness)
    ``1 - max(|x|, |y|)`` of the element's pixel centroid in normalised device
    coordinates (-1..1): 1 at the centre of the view, 0 on the border of the
    frame and beyond, with rectangular level lines that follow the frame's
    shape (a round distance would reach 0 at the middle of the edges but not in
    the corners).  0 for an invisible element or a non-finite centroid.
D (distance)
    The camera-space depth of the element, clamped to [near_clip, 1e12]: the
    near-plane clamp.  An element touching or behind the camera (depth <= 0),
    or a depth of 1e-9, counts as lying on the near plane, which is where its
    visible pixels are at the closest; an unknown (NaN) depth too.  The engine
    passes the camera's ``clip_start`` as ``near_clip`` (Blender's default,
    0.1, otherwise).  D is therefore never zero or negative in a division.
V (visibility), normalised
    ``V = (A * P / D) / visibility_scale`` where ``visibility_scale`` is the
    largest ``A * P / D`` among the frame's competing elements (visible
    candidates within the area limit), so the most visible of them has V = 1.
    Raw A*P/D is in 1/scene-units and spans orders of magnitude with the scene
    scale, while equation (3) adds the selection weight I to V: only a V on a
    known scale gives I a meaning.  With the default I = 0.5, an element
    selected last frame keeps its place against an unselected rival of equal
    priority K unless the rival is more visible by half of the frame's top
    visibility - strong hysteresis, as the paper wants ("no element repeatedly
    changed from raster to ray tracing") - while a newly central, large element
    still displaces weakly visible ones.  The normalisation only rescales V
    within a frame, so orders by V are the paper's; C = V * Q and R use this V,
    and the selection log shows it, so every row can be recomputed from its own
    columns.  Non-competing elements use the same scale (their V may exceed 1).
K (priority) = 0
    The designer's "never worth tracing" (the property's description): such an
    element is treated as not a candidate (reason ``not_candidate``), in every
    mode.  K is clamped to [0, 1e15].
Relevance (the ``relevance`` setting)
    ``paper`` (default) is equation (3).  ``error`` replaces V in it by V times
    the element's expected benefit of tracing, per pixel (``FrameElements.benefit``:
    a running estimate of how much its traced image differs from its raster
    image, kept by :mod:`.benefit`), normalised like V so that the most
    beneficial competing element has 1 and I keeps its meaning.  The logged V
    stays the paper's; the rows carry the normalised product as ``benefit``.
Budget as a fraction (``budget_at``)
    When set (0 = raster, 1 = ray traced frame time) and no T is given, T is that
    fraction of the predicted ray tracing time of every visible candidate (what a
    RAYTRACE frame traces): the budget follows the machine without a
    millisecond figure.  Replays resolve it to milliseconds once, before the
    first frame (``engine/runs/calibration.py``); this per-frame form serves single renders.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .. import defaults
from ..finite import finite
from .cost_model import MAX_PREDICTED_MS, normalise_cost_mode
from ..schema import MODES, ORDERS, RELEVANCES

# Blender's default camera clip_start: the near-plane clamp of D when the engine
# does not pass the camera's own.
NEAR_CLIP_DISTANCE = 0.1
# Clamps that keep every term finite whatever the scene holds.
MIN_NEAR_CLIP_DISTANCE = 1e-6
FAR_DISTANCE = 1e12
MAX_PRIORITY = 1e15
MAX_RT_COST = 1e12
# The smallest Q the BENEFIT choice divides an item's value by (the Blender property's own minimum).
MIN_RT_COST = 1e-3
MAX_RAYS_PER_PIXEL = 1e6
MAX_SELECTION_WEIGHT = 1e6
MAX_VISIBILITY = 1e12


def clamp_finite(values, *, nan: float, low: float, high: float) -> np.ndarray:
    array = finite(values, nan=nan, posinf=high, neginf=low)
    return np.clip(array, low, high)


@dataclass
class FrameElements:
    """Every element of one frame, as whole arrays of length n.

    Built by the engine from its snapshot and G-buffer; checked once here (shapes
    and types), then sanitised so that no later term can be NaN or infinite.
    Element order and names must be stable across frames; names must be unique.

    ``area_px``       pixel count of the element in the element-id target
    ``frame_px``      width * height of the frame
    ``centre_ndc``    (n, 2) pixel centroid in normalised device coordinates (-1..1),
                      any value where ``area_px == 0``
    ``distance``      camera-space depth (may be <= 0, tiny or huge: see module docstring)
    ``priority``      K (>= 0); ``rt_cost`` Q (>= 0)
    ``rays_per_pixel`` rays one pixel of the element costs with its effects
    ``near_clip``     the camera's clip_start, the near-plane clamp of D
    ``benefit``       expected traced-vs-raster difference per pixel (``error`` relevance)
    Optional arrays default to: candidate True, centre 0, distance 1, K 1, Q 1,
    no effects, 1 ray per pixel, benefit 1.  Sanitising: pixel counts are clipped to
    [0, frame_px]; a NaN K counts as 0, a NaN Q as 1, NaN rays as 0; K, Q and
    rays are clipped to [0, a large finite maximum]; a near_clip that is not a
    positive finite number falls back to NEAR_CLIP_DISTANCE.
    """

    names: Sequence[str]
    area_px: np.ndarray
    frame_px: int
    candidate: np.ndarray | None = None
    centre_ndc: np.ndarray | None = None
    distance: np.ndarray | None = None
    priority: np.ndarray | None = None
    rt_cost: np.ndarray | None = None
    shadows: np.ndarray | None = None
    reflections: np.ndarray | None = None
    refractions: np.ndarray | None = None
    rays_per_pixel: np.ndarray | None = None
    near_clip: float = NEAR_CLIP_DISTANCE
    benefit: np.ndarray | None = None

    def __post_init__(self):
        self.names = list(map(str, self.names))
        n = len(self.names)
        if len(set(self.names)) != n:
            raise ValueError("element names must be unique (the previous selection is keyed by name)")

        def column(name, default, dtype):
            value = getattr(self, name)
            array = np.full(n, default, dtype=dtype) if value is None else np.asarray(value)
            if array.shape != (n,):
                raise ValueError(f"{name} has shape {array.shape}, expected ({n},) like names")
            return array

        self.frame_px = int(max(0, self.frame_px))
        area = column("area_px", 0, np.int64)
        if area.dtype.kind == "f":
            area = np.nan_to_num(area, nan=0.0, posinf=0.0, neginf=0.0)
        self.area_px = np.clip(area.astype(np.int64), 0, self.frame_px)
        for name in ("candidate", "shadows", "reflections", "refractions"):
            setattr(self, name, column(name, name == "candidate", bool).astype(bool))
        centre = np.zeros((n, 2)) if self.centre_ndc is None else np.asarray(self.centre_ndc, dtype=np.float64)
        if centre.shape != (n, 2):
            raise ValueError(f"centre_ndc has shape {centre.shape}, expected ({n}, 2)")
        self.centre_ndc = centre
        near = float(self.near_clip)
        self.near_clip = max(near, MIN_NEAR_CLIP_DISTANCE) if 0 < near < FAR_DISTANCE else NEAR_CLIP_DISTANCE
        self.distance = column("distance", 1.0, np.float64).astype(np.float64)
        self.priority = clamp_finite(column("priority", 1.0, np.float64), nan=0.0, low=0.0, high=MAX_PRIORITY)
        self.rt_cost = clamp_finite(column("rt_cost", 1.0, np.float64), nan=1.0, low=0.0, high=MAX_RT_COST)
        self.rays_per_pixel = clamp_finite(column("rays_per_pixel", 1.0, np.float64), nan=0.0, low=0.0,
                                      high=MAX_RAYS_PER_PIXEL)
        self.benefit = clamp_finite(column("benefit", 1.0, np.float64), nan=0.0, low=0.0, high=MAX_VISIBILITY)

    def __len__(self) -> int:
        return len(self.names)


@dataclass
class SelectionSettings:
    """The scene's settings of the heuristic (``Scene.phrt``), checked once.

    ``mode``, ``cost_mode``, ``relevance`` and ``order`` accept any case ('HYBRID',
    'paper', 'PAPER'...).  ``budget_at`` (None or 0..1): see "Budget as a fraction".
    """

    budget_ms: float = defaults.BUDGET_MS
    selection_weight: float = defaults.SELECTION_WEIGHT
    max_area_fraction: float = defaults.MAX_AREA_FRACTION
    mode: str = "HYBRID"
    cost_mode: str = "measured"
    relevance: str = "paper"
    order: str = "relevance"
    budget_at: float | None = None

    def __post_init__(self):
        self.mode = str(self.mode).strip().upper()
        if self.mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}, not {self.mode!r}")
        self.cost_mode = normalise_cost_mode(self.cost_mode)
        self.relevance = str(self.relevance).strip().lower()
        if self.relevance not in RELEVANCES:
            raise ValueError(f"relevance must be one of {RELEVANCES} (any case), not {self.relevance!r}")
        self.order = str(self.order).strip().lower()
        if self.order not in ORDERS:
            raise ValueError(f"order must be one of {ORDERS} (any case), not {self.order!r}")
        if self.budget_at is not None:
            fraction = float(self.budget_at)
            if not 0.0 <= fraction <= 1.0:
                raise ValueError(f"budget_at must be within 0..1, not {self.budget_at!r}")
            self.budget_at = fraction
        for name in ("budget_ms", "selection_weight", "max_area_fraction"):
            value = float(getattr(self, name))
            if np.isnan(value) or value < 0:
                raise ValueError(f"{name} must be a number >= 0, not {value!r}")
            setattr(self, name, value)
        self.budget_ms = min(self.budget_ms, MAX_PREDICTED_MS)
        self.selection_weight = min(self.selection_weight, MAX_SELECTION_WEIGHT)


@dataclass
class ElementTerms:
    """The paper's terms of every element of a frame (arrays of length n)."""

    area_fraction: np.ndarray          # A
    centre_closeness: np.ndarray       # P
    distance: np.ndarray               # D (near-clamped)
    visibility: np.ndarray             # V (normalised, see module docstring)
    visibility_scale: float            # the frame's largest A*P/D among competing elements
    cost: np.ndarray                   # C = V * Q
    previously_selected: np.ndarray    # S
    relevance: np.ndarray              # R = (S * I + V) * K
    visible: np.ndarray
    candidate: np.ndarray              # tagged and K > 0
    within_area: np.ndarray            # A <= max_area_fraction
    weighted_visibility: np.ndarray | None = None  # V x benefit, normalised (``error`` relevance)


def element_terms(elements: FrameElements, previously_selected: np.ndarray, selection_weight: float,
                  max_area_fraction: float, relevance: str = "paper") -> ElementTerms:
    """Equations (1)-(3) of the paper on whole arrays, with the clamps of the
    module docstring; with ``relevance='error'`` V in (3) is weighted by the
    elements' benefit.  No term is NaN or infinite."""
    frame_px = elements.frame_px
    area_px = elements.area_px
    visible = area_px > 0 if frame_px > 0 else np.zeros(len(elements), dtype=bool)
    area_fraction = area_px / frame_px if frame_px > 0 else np.zeros(len(elements))
    area_fraction = np.clip(area_fraction, 0.0, 1.0)

    centre = elements.centre_ndc
    centre_ok = visible & np.all(np.isfinite(centre), axis=1)
    edge_distance = np.max(np.abs(np.where(centre_ok[:, None], centre, 1.0)), axis=1) if len(elements) else np.zeros(0)
    centre_closeness = np.where(centre_ok, np.clip(1.0 - edge_distance, 0.0, 1.0), 0.0)

    near = elements.near_clip
    distance = clamp_finite(elements.distance, nan=near, low=near, high=FAR_DISTANCE)

    candidate = elements.candidate & (elements.priority > 0)
    within_area = area_fraction <= max_area_fraction
    competing = candidate & visible & within_area
    raw_visibility = area_fraction * centre_closeness / distance
    scale = float(raw_visibility[competing].max()) if np.any(competing) else 0.0
    if not (np.isfinite(scale) and scale > 0):
        scale = 1.0
    visibility = clamp_finite(raw_visibility / scale, nan=0.0, low=0.0, high=MAX_VISIBILITY)

    cost = visibility * elements.rt_cost
    selected_before = np.asarray(previously_selected, dtype=bool)
    weighted = None
    relevance_visibility = visibility
    if str(relevance).lower() == "error":
        raw_weighted = raw_visibility * elements.benefit
        weighted_scale = float(raw_weighted[competing].max()) if np.any(competing) else 0.0
        if not (np.isfinite(weighted_scale) and weighted_scale > 0):
            weighted_scale = 1.0
        weighted = clamp_finite(raw_weighted / weighted_scale, nan=0.0, low=0.0, high=MAX_VISIBILITY)
        relevance_visibility = weighted
    relevance = (selected_before * float(selection_weight) + relevance_visibility) * elements.priority
    return ElementTerms(
        area_fraction=area_fraction, centre_closeness=centre_closeness, distance=distance,
        visibility=visibility, visibility_scale=scale, cost=cost, previously_selected=selected_before,
        relevance=relevance, visible=visible, candidate=candidate, within_area=within_area,
        weighted_visibility=weighted,
    )
