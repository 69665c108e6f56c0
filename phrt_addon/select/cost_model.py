"""Cost model of the selection heuristic: predicted milliseconds, learned each frame.

The paper budgets in abstract cost units (C = V * Q); a renderer has to budget in
time.  This module turns an element's cost into predicted milliseconds of ray
tracing, predicts the other stages of the frame (raster, selection, composite) so
that the heuristic knows the time T left for ray tracing, and learns all of it
from the times the engine measures after each frame.  Plain Python + numpy.

Two cost modes, both always learned so that a report can compare them:

``paper``
    Faithful to the paper: predicted ms = ``paper_ms_per_cost * C`` with C = V * Q
    (V as the heuristic normalises it).  The factor is fitted to the measured trace
    time of the frame divided by the summed C of the selection.
``measured``
    Predicted ms = ``Q * area_px * rays_per_pixel * rays_ratio * ms_per_ray * residual``:
    the element's pixel count, the rays one of its pixels costs (filled by the
    engine, corrected per element by ``rays_ratio`` learned from the rays the
    tracer really cast for it), the measured cost per ray of its effects (learned
    per effect), a global ``residual`` that absorbs what the per-effect split
    cannot explain (mixed effects, per-frame overhead), and the designer's Q.

Q is a designer multiplier (docs/properties.md): with Q = 1 the prediction is
the time the model expects to measure; Q = 2 charges an element twice its
expected time against the budget.  The learning itself never involves Q in the
measured mode (rays and milliseconds are physical).

Every quantity is learned by ``robust_estimate.RobustEstimate`` (cold start, noise, outliers and
step changes of the budget loop).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

import numpy as np

from ..schema import COST_MODES, EFFECTS
from .robust_estimate import RobustEstimate

STAGES = ("raster", "select", "composite")

# Priors, used only until the first measurement of each quantity.  Rough values
# for a 640x480 frame on 2 CPU cores (see docs/platform-notes.md).
STAGE_PRIOR_MS = {"raster": 50.0, "select": 1.0, "composite": 5.0}
# The fixed part of a frame that traces anything (layers read back, the moving objects' BVH,
# per-frame tables): learned from the trace time its effects' own timers do not account for;
# not charged before its first measurement (this prior only seeds the estimator).
TRACE_OVERHEAD_PRIOR_MS = 1.0
MS_PER_RAY_PRIOR = {"shadows": 1.5e-4, "reflections": 3e-4, "refractions": 3e-4}
# ms per unit of the paper's cost C (V normalised to 1 for the frame's most
# visible candidate): the most visible element with Q = 1 is guessed at 20 ms.
PAPER_MS_PER_COST_PRIOR = 20.0

# An effect never measured yet in this replay is charged this many times its prior cost per ray:
# a first guess that is too cheap would select an element for one frame and drop it the next
# (an over-budget frame and two selection flips); one measurement replaces the guess.
UNMEASURED_MARGIN = 1.5
# A learned cost that prices every frame out is never measured again (the first traced frames pay
# first-use work; a hiccup of this machine doubles a frame).  After STALE_FRAMES frames that could
# have traced and did not, it is divided by STALE_DISCOUNT (not reset to the prior: a cost measured
# right, too dear for the time left, is then not traced at once at a guessed price, a sure
# overrun); each revision doubles the idle frames before the next (at most STALE_MAX_FRAMES), so a
# cost that really is too dear is probed less and less often.  The fixed trace overhead here and
# BENEFIT's per-effect costs (``item_costs.py``) follow this rule.
STALE_FRAMES = 8
STALE_MAX_FRAMES = 128
STALE_DISCOUNT = 2.0
# Smallest stage time worth a logarithm (a stage measured at 0 ms is this).
STAGE_FLOOR_MS = 1e-3
# Upper clamp of any predicted time: keeps sums finite whatever the input.
MAX_PREDICTED_MS = 1e12
# How fast the share of rays per effect (used to mix per-effect costs) follows.
RAY_SHARE_SMOOTHING = 0.3


def normalise_cost_mode(cost_mode: str) -> str:
    """'paper' or 'measured' from either spelling ('PAPER' is the Blender enum)."""
    mode = str(cost_mode).strip().lower()
    if mode not in COST_MODES:
        raise ValueError(f"cost_mode must be one of {COST_MODES} (any case), not {cost_mode!r}")
    return mode


@dataclass
class FrameStats:
    """What the engine measured for one frame, handed to :meth:`CostModel.observe`.

    A time left at None was not measured and teaches nothing.  ``effect_ms`` and
    ``effect_rays`` are keyed by the names in ``EFFECTS``; ``element_rays`` is the
    number of rays cast for each element of the frame, in the element order of the
    selection result the frame was traced with (0 for elements not traced).
    """

    raster_ms: float | None = None
    select_ms: float | None = None
    composite_ms: float | None = None
    trace_ms: float | None = None
    effect_ms: Mapping[str, float] = field(default_factory=dict)
    effect_rays: Mapping[str, float] = field(default_factory=dict)
    element_rays: Sequence[float] | np.ndarray | None = None
    # Of ``trace_ms``, what no effect's timer holds (the fixed cost of tracing anything); None:
    # not measured (the whole trace time is then shared between the effects, as per-ray cost).
    trace_overhead_ms: float | None = None
    trace_wanted: bool = False  # the frame could have traced (a candidate in view, not RASTER)


def _finite_at_least(value, low: float, strict: bool) -> float | None:
    """``value`` as a float when it is finite and above ``low`` (or equal, unless ``strict``);
    None when it is not (unusable measurements teach nothing)."""
    try:
        value = float(value)
    except (TypeError, ValueError):
        return None
    return value if math.isfinite(value) and (value > low or (value == low and not strict)) else None


def _finite_non_negative(value) -> float | None:
    return _finite_at_least(value, 0.0, strict=False)


def _finite_positive(value) -> float | None:
    return _finite_at_least(value, 0.0, strict=True)


class CostModel:
    """Predicts the milliseconds of each stage of a frame and learns them.

    The engine's loop, once per frame::

        time_left_ms = model.time_left(budget_ms)          # T of the paper
        result = heuristic.select(elements, previous, settings, model)
        ... trace result's selection, composite ...
        model.observe(FrameStats(...), result)
    """

    def __init__(self, *, stage_prior_ms: Mapping[str, float] | None = None,
                 ms_per_ray_prior: Mapping[str, float] | None = None,
                 paper_ms_per_cost_prior: float = PAPER_MS_PER_COST_PRIOR,
                 smoothing: float = 0.3, gate_ratio: float = 1.3, confirm: int = 3, window: int = 5):
        self._estimator_settings = dict(smoothing=smoothing, gate_ratio=gate_ratio, confirm=confirm, window=window)
        stage_priors = {**STAGE_PRIOR_MS, **(stage_prior_ms or {})}
        ray_priors = {**MS_PER_RAY_PRIOR, **(ms_per_ray_prior or {})}
        self._stage_ms = {stage: self._estimate(stage_priors[stage], floor=STAGE_FLOOR_MS) for stage in STAGES}
        self._ms_per_ray = {effect: self._estimate(ray_priors[effect]) for effect in EFFECTS}
        self._ray_share = np.full(len(EFFECTS), 1.0 / len(EFFECTS))
        self._paper_ms_per_cost = self._estimate(paper_ms_per_cost_prior)
        self._residual = self._estimate(1.0)
        self._trace_overhead = self._estimate(TRACE_OVERHEAD_PRIOR_MS, floor=STAGE_FLOOR_MS)
        self._overhead_idle, self._overhead_stale_after = 0, STALE_FRAMES  # frames (STALE_FRAMES)
        self._rays_ratio: dict[str, RobustEstimate] = {}
        # The learned ratios as an array in the last frame's element order (the
        # engine keeps the order stable, so lookups by name are rarely needed).
        self._rays_ratio_names: list[str] = []
        self._rays_ratio_values = np.ones(0)

    def _estimate(self, prior: float, floor: float = 0.0) -> RobustEstimate:
        return RobustEstimate(prior, floor=floor, **self._estimator_settings)

    # -- predictions ---------------------------------------------------------

    def stage_ms(self) -> dict[str, float]:
        """Predicted ms of the non-trace stages: raster, select, composite."""
        return {stage: estimate.value for stage, estimate in self._stage_ms.items()}

    def non_trace_ms(self) -> float:
        return float(sum(self.stage_ms().values()))

    def time_left(self, budget_ms: float, raster_ms: float | None = None) -> float:
        """T: the frame budget minus the raster, selection and composite time of this frame,
        never negative (finite for any finite budget).  ``raster_ms``: what this frame's raster
        half already took (measured: the selection runs after it), else the predicted one."""
        budget = float(np.nan_to_num(budget_ms, nan=0.0, posinf=MAX_PREDICTED_MS, neginf=0.0))
        stages = self.stage_ms()
        if raster_ms is not None:
            stages["raster"] = float(np.clip(np.nan_to_num(raster_ms, nan=stages["raster"], posinf=MAX_PREDICTED_MS),
                                             0.0, MAX_PREDICTED_MS))
        return float(min(max(budget - sum(stages.values()), 0.0), MAX_PREDICTED_MS))

    def trace_overhead_ms(self) -> float:
        """Predicted fixed ms of a frame that traces anything (charged once against T); 0 until
        measured (an engine that does not measure it has it in the per-ray costs)."""
        return self._trace_overhead.value if self._trace_overhead.observations else 0.0

    def ms_per_ray(self) -> dict[str, float]:
        return {effect: estimate.value for effect, estimate in self._ms_per_ray.items()}

    def state(self) -> dict[str, float]:
        """Everything learned, flat, for logs and the report."""
        state = {f"{stage}_ms": value for stage, value in self.stage_ms().items()}
        state.update({f"{effect}_ms_per_ray": value for effect, value in self.ms_per_ray().items()})
        state["paper_ms_per_cost"] = self._paper_ms_per_cost.value
        state["measured_residual"] = self._residual.value
        state["trace_overhead_ms"] = self.trace_overhead_ms()
        return state

    def predict_element_ms(self, elements, cost: np.ndarray, cost_mode: str) -> np.ndarray:
        """Predicted ray tracing ms of every element (charged against T if selected).

        ``elements`` is a :class:`heuristic.FrameElements`; ``cost`` is the
        paper's C per element (used by the ``paper`` mode only).
        """
        if normalise_cost_mode(cost_mode) == "paper":
            predicted = self._paper_ms_per_cost.value * np.asarray(cost, dtype=np.float64)
        else:
            predicted = self._physical_ms(elements) * elements.rt_cost * self._residual.value
        return np.clip(np.nan_to_num(predicted, nan=0.0, posinf=MAX_PREDICTED_MS, neginf=0.0),
                       0.0, MAX_PREDICTED_MS)

    def _rays_ratio_of(self, names: Sequence[str]) -> np.ndarray:
        if not self._rays_ratio:
            return np.ones(len(names))
        if self._rays_ratio_names != names:
            lookup = self._rays_ratio.get
            self._rays_ratio_values = np.fromiter(
                ((estimate.value if estimate is not None else 1.0) for estimate in map(lookup, names)),
                dtype=np.float64, count=len(names))
            self._rays_ratio_names = list(names)
        return self._rays_ratio_values

    def _element_ms_per_ray(self, elements) -> np.ndarray:
        """Cost per ray of each element's effects: the per-effect costs weighted by
        the share of rays each effect has had lately (an element's own split of
        rays between its effects is not measured); the all-effects mix for an
        element with no effect flagged."""
        per_effect = np.array([self._ms_per_ray[effect].value * (UNMEASURED_MARGIN if not
                               self._ms_per_ray[effect].observations else 1.0) for effect in EFFECTS])
        weights = np.maximum(self._ray_share, 1e-3)
        effects = np.stack([elements.shadows, elements.reflections, elements.refractions], axis=1).astype(np.float64)
        numerator = effects @ (weights * per_effect)
        denominator = effects @ weights
        overall = float(weights @ per_effect / weights.sum())
        return np.where(denominator > 0, numerator / np.where(denominator > 0, denominator, 1.0), overall)

    def _physical_ms(self, elements) -> np.ndarray:
        """Expected ms without Q and without the residual."""
        rays = elements.area_px * elements.rays_per_pixel * self._rays_ratio_of(elements.names)
        return rays * self._element_ms_per_ray(elements)

    # -- learning ------------------------------------------------------------

    def observe(self, stats: FrameStats, result=None) -> None:
        """Learn from the times measured for one frame.

        ``result`` is the :class:`heuristic.SelectionResult` the frame was traced
        with; without it only the stage times and per-effect costs are learned.
        Unusable measurements (None, NaN, negative) are ignored.
        """
        for stage in STAGES:
            measured = getattr(stats, f"{stage}_ms")
            if measured is not None:
                self._stage_ms[stage].update(measured)
        trace_ms = _finite_positive(stats.trace_ms)
        self._revise_stale_overhead(trace_ms is not None, bool(stats.trace_wanted))
        overhead = _finite_non_negative(stats.trace_overhead_ms)
        if trace_ms is not None and overhead is not None:
            overhead = min(overhead, trace_ms)
            self._trace_overhead.update(overhead)
            # What is left is the effects' (per-ray) time.
            trace_ms = _finite_positive(trace_ms - overhead)
        effect_rays = np.array([_finite_positive(stats.effect_rays.get(effect, 0)) or 0.0 for effect in EFFECTS])
        effect_ms = np.array([_finite_positive(stats.effect_ms.get(effect, 0)) or 0.0 for effect in EFFECTS])
        element_rays = None
        if result is not None and stats.element_rays is not None:
            element_rays = np.nan_to_num(np.asarray(stats.element_rays, dtype=np.float64), nan=0.0,
                                         posinf=0.0, neginf=0.0)
            if element_rays.shape != (len(result.names),):
                raise ValueError(f"element_rays has shape {element_rays.shape}, expected ({len(result.names)},)")
        self._learn_ms_per_ray(trace_ms, effect_ms, effect_rays, element_rays, result)
        if result is None or trace_ms is None or not np.any(result.selected):
            return
        selected = np.asarray(result.selected, dtype=bool)
        if element_rays is not None:
            self._learn_rays_ratio(result, element_rays, selected)
        elements = result.elements
        expected_ms = float(np.sum(self._physical_ms(elements)[selected]))
        if expected_ms > 0:
            self._residual.update(trace_ms / expected_ms)
        summed_cost = float(np.sum(np.asarray(result.C)[selected]))
        if summed_cost > 0:
            self._paper_ms_per_cost.update(trace_ms / summed_cost)

    def _revise_stale_overhead(self, measured: bool, wanted: bool) -> None:
        """The fixed trace overhead, not measured for its stale period of frames that could have
        traced, is divided by STALE_DISCOUNT (see STALE_FRAMES)."""
        if measured or not wanted:
            self._overhead_idle = 0 if measured else self._overhead_idle
            return
        self._overhead_idle += 1
        if self._overhead_idle >= self._overhead_stale_after and self._trace_overhead.observations:
            self._trace_overhead.revise(STALE_DISCOUNT)
            if self._trace_overhead.observations > 1:  # measured once (a first, cold trace): not slowed
                self._overhead_stale_after = min(2 * self._overhead_stale_after, STALE_MAX_FRAMES)
            self._overhead_idle = 0

    def _learn_ms_per_ray(self, trace_ms, effect_ms, effect_rays, element_rays, result) -> None:
        total_rays = float(effect_rays.sum())
        if total_rays > 0:
            share = effect_rays / total_rays
            self._ray_share += RAY_SHARE_SMOOTHING * (share - self._ray_share)
        elif element_rays is not None:
            total_rays = float(element_rays.sum())
        if trace_ms is None or total_rays <= 0:
            return
        traced = effect_rays > 0
        if np.any(traced) and effect_ms[traced].sum() > 0:
            # The frame's trace time split between effects as the effects' own
            # timers split it (so per-frame overhead is shared, not lost).
            attributed_ms = trace_ms * effect_ms / effect_ms[traced].sum()
            for index, effect in enumerate(EFFECTS):
                if traced[index] and attributed_ms[index] > 0:
                    self._ms_per_ray[effect].update(attributed_ms[index] / effect_rays[index])
            return
        # Only a total: one cost per ray for the effects that were traced.
        if not np.any(traced) and result is not None:
            selected = np.asarray(result.selected, dtype=bool)
            elements = result.elements
            traced = np.array([np.any(np.asarray(getattr(elements, effect))[selected]) for effect in EFFECTS])
        for index, effect in enumerate(EFFECTS):
            if traced[index]:
                self._ms_per_ray[effect].update(trace_ms / total_rays)

    def _learn_rays_ratio(self, result, element_rays: np.ndarray, selected: np.ndarray) -> None:
        elements = result.elements
        expected_rays = elements.area_px * elements.rays_per_pixel
        usable = np.flatnonzero(selected & (expected_rays > 0) & (element_rays > 0))
        in_cached_order = self._rays_ratio_names == result.names
        for index in usable.tolist():
            name = result.names[index]
            estimate = self._rays_ratio.get(name)
            if estimate is None:
                estimate = self._rays_ratio[name] = self._estimate(1.0)
            estimate.update(element_rays[index] / expected_rays[index])
            if in_cached_order:
                self._rays_ratio_values[index] = estimate.value
