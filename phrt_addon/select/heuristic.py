"""Selection heuristic of the paper (sections IV and V): which elements are ray traced.

Plain Python + numpy (no ``bpy``), one frame at a time:

1. the paper's terms of every element (equations 1-3): area A, centre closeness
   P, distance D, visibility V, cost C and relevance R (``selection_terms.py``,
   where the paper's vague points are decided);
2. the selection graph of section V.B (:class:`SelectionGraph`): one node per
   competing element with its predicted cost in milliseconds and its relevance,
   the cost-ordered list and the relevance order;
3. node selection of section V.C within the time left T (:func:`select`), with
   the graph rebuilt every frame (V.D) and one explainable row per element
   (:meth:`SelectionResult.rows`, the columns of docs/formats.md).

An element is an object tagged ``candidate``, or the faces of one material slot
whose material is tagged.  Non-candidates are passed too: they get rows (reason
``not_candidate``) and are never selected.

Decisions where the paper is vague
----------------------------------
Modes
    ``HYBRID`` applies the budget and the area limit.  ``RAYTRACE`` selects
    every visible candidate (K > 0) with no budget and no area limit; T is still
    reported.  ``RASTER`` is ray tracing with no time at all: T = 0 and nothing
    is selected, not even an element predicted to cost 0 ms; visible candidates
    within the area limit get ``over_budget`` (no time for ray tracing), those
    over it ``over_area``.
Node selection (V.C)
    Nodes are ordered by relevance R, highest first; ties go to the cheaper
    node, then to the lower element index (the engine keeps a stable element
    order), so equal input gives equal output.  One greedy pass goes down that
    order taking every node whose predicted cost still fits the time left: at
    each step the paper's "most relevant node whose cost C is small enough",
    because a node skipped earlier could not fit a larger remainder.  (The
    paper's two phases, N nodes for its N stream processors and then the rest,
    select the same set; the trace stage traces a frame's selection as one
    batch, so no tracing order is kept.)  A node predicted at 0 ms always fits.  The predicted cost of the
    selection never exceeds T: both are summed in the same order.
Relevance edges
    The paper links every node to all nodes of higher relevance: O(n^2) edges.
    Their information is the relevance order, which is all selection needs;
    :meth:`SelectionGraph.relevance_edges` materialises them for debugging only.
Greedy order (the ``order`` setting)
    ``relevance`` (default) is the paper's: highest R first.  ``relevance_per_ms``
    orders by R per predicted millisecond (the knapsack's greedy ratio); ties
    and the pass itself are the same.
Hysteresis margin
    Computed by ``tests/core/hysteresis.py`` for the property tests: for a competing
    element, how much its V can change (with everything else, its cost and the
    frame's visibility scale unchanged) before its relevance crosses that of a
    competing element in the other state.  Greedy selection keeps the element's
    state within that margin: a selected element sinking past selected ones only
    still fits, an unselected one rising past unselected ones still does not.
    At a steady selection, a selected element's margin against an unselected
    rival of equal K is ``I + (V_element - V_rival)``: the selection weight I
    widens it by exactly I.
"""
from __future__ import annotations

from dataclasses import dataclass
from dataclasses import replace as dataclass_replace
from functools import cached_property
from itertools import compress
from typing import Mapping, Sequence

import numpy as np

from .cost_model import MAX_PREDICTED_MS, CostModel
from ..schema import ORDERS, SELECTION_COLUMNS
from .selection_terms import ElementTerms, FrameElements, SelectionSettings, clamp_finite, element_terms


# The smallest predicted cost an R-per-ms order divides by (a 0 ms node comes first).
MIN_ORDER_MS = 1e-6

# Above this many nodes, relevance_edges() refuses (it is quadratic).
MAX_DEBUG_EDGE_NODES = 2000
# A hysteresis margin with no element of the other state to cross.
UNBOUNDED_MARGIN = float(np.finfo(np.float64).max)


def previously_selected_mask(names: Sequence[str], previous_selection) -> np.ndarray:
    """S per element from last frame's selection, keyed by element name.

    ``previous_selection`` may be None (first frame), a :class:`SelectionResult`,
    a mapping name -> selected, or an iterable of selected names.  Names that
    are not in this frame are ignored; new names get S = 0.
    """
    n = len(names)
    if previous_selection is None:
        return np.zeros(n, dtype=bool)
    if isinstance(previous_selection, SelectionResult):
        if previous_selection.names == names:  # the usual case: a stable element order
            return previous_selection.selected.copy()
        chosen = previous_selection.selected_names()
    elif isinstance(previous_selection, Mapping):
        chosen = {str(name) for name, was_selected in previous_selection.items() if was_selected}
    else:
        chosen = {str(name) for name in previous_selection}
    if not chosen:
        return np.zeros(n, dtype=bool)
    return np.fromiter((name in chosen for name in names), dtype=bool, count=n)


class SelectionGraph:
    """The selection graph of section V.B for one frame.

    Nodes are the competing elements (``nodes`` holds their element indices),
    each with its predicted cost in ms (``cost_ms``, the paper's C turned into
    time by the cost model) and its relevance R.  The paper's two kinds of
    edges are kept as sorted orders: ``cost_order`` (the cost-ordered linked
    list, cheapest first; built on first use) and ``relevance_order`` (highest
    relevance first, ties: cheaper, then lower index).  Building is one sort:
    O(n log n).
    """

    def __init__(self, nodes: np.ndarray, cost_ms: np.ndarray, relevance: np.ndarray, order: str = "relevance"):
        self.nodes = np.asarray(nodes, dtype=np.int64)
        self.cost_ms = np.asarray(cost_ms, dtype=np.float64)
        self.relevance = np.asarray(relevance, dtype=np.float64)
        if not (self.nodes.shape == self.cost_ms.shape == self.relevance.shape):
            raise ValueError("nodes, cost_ms and relevance must have the same length")
        if order == "relevance_per_ms":
            key = self.relevance / np.maximum(self.cost_ms, MIN_ORDER_MS)
        elif order == "relevance":
            key = self.relevance
        else:
            raise ValueError(f"order must be one of {ORDERS}, not {order!r}")
        # The greedy pass's order (the paper's: relevance; or relevance per predicted ms).
        self.relevance_order = np.lexsort((self.nodes, self.cost_ms, -key))

    def __len__(self) -> int:
        return len(self.nodes)

    @cached_property
    def cost_order(self) -> np.ndarray:
        return np.lexsort((self.nodes, self.cost_ms))

    def cost_edges(self) -> np.ndarray:
        """(m, 2) element-index pairs: each node -> the next cheaper node (the
        paper's linked list, from the most expensive node down)."""
        ordered = self.nodes[self.cost_order[::-1]]
        return np.stack([ordered[:-1], ordered[1:]], axis=1) if len(ordered) > 1 else np.zeros((0, 2), np.int64)

    def relevance_edges(self) -> np.ndarray:
        """(m, 2) element-index pairs: each node -> every node of strictly higher
        relevance.  Quadratic: for debugging, refused above MAX_DEBUG_EDGE_NODES."""
        if len(self) > MAX_DEBUG_EDGE_NODES:
            raise ValueError(f"{len(self)} nodes: relevance edges are O(n^2), exported up to "
                             f"{MAX_DEBUG_EDGE_NODES} nodes")
        source, target = np.nonzero(self.relevance[None, :] > self.relevance[:, None])
        return np.stack([self.nodes[source], self.nodes[target]], axis=1)

    def select(self, time_left_ms: float) -> tuple[np.ndarray, float]:
        """Node selection of section V.C.

        Returns (selected mask over nodes, predicted ms of the selection <=
        time_left_ms).  O(n): the
        prefix of the relevance order that fits is found with one cumulative
        sum; after it, a pass that stops when even the cheapest node still ahead
        no longer fits.
        """
        n = len(self)
        selected = np.zeros(n, dtype=bool)
        if n == 0:
            return selected, 0.0
        order = self.relevance_order
        costs = self.cost_ms[order]
        cumulative = np.cumsum(costs)
        fitting = int(np.searchsorted(cumulative, time_left_ms, side="right"))
        taken = list(range(fitting))
        spent = float(cumulative[fitting - 1]) if fitting else 0.0
        if fitting < n - 1:
            cheapest_ahead = np.minimum.accumulate(costs[::-1])[::-1].tolist()
            cost_list = costs.tolist()
            for position in range(fitting + 1, n):
                if spent + cheapest_ahead[position] > time_left_ms:
                    break
                cost = cost_list[position]
                if spent + cost <= time_left_ms:
                    spent += cost
                    taken.append(position)
        selected[order[np.asarray(taken, dtype=np.int64)]] = True
        return selected, spent


@dataclass
class SelectionResult:
    """The decision of one frame, with every term, for the engine and the logs.

    Arrays have one entry per element, in the input's element order.  The
    paper's short names are available as properties (A, P, D, V, C, R, S, K, Q).
    ``predicted_ms`` is each element's predicted ray tracing ms (what it is
    charged against T), ``predicted_trace_ms`` the total of the selection,
    ``time_left_ms`` the T the selection was fitted to, ``budget_ms`` the frame
    budget it came from (resolved from ``budget_at`` when that was set).
    """

    elements: FrameElements
    terms: ElementTerms
    selected: np.ndarray
    reason: list[str]
    predicted_ms: np.ndarray
    predicted_trace_ms: float
    time_left_ms: float
    mode: str
    cost_mode: str
    selection_weight: float
    frame: int | None = None
    budget_ms: float | None = None
    relevance_mode: str = "paper"
    order: str = "relevance"
    # The BENEFIT selection's items: per effect, the elements whose effect is traced (None: every
    # tagged effect of a selected element), and each element's summed item value.
    effects: dict | None = None
    benefit_estimate: np.ndarray | None = None
    # BENEFIT: per element the lowest rate its traced effects came at (1: full, 0: not traced).
    item_rate: np.ndarray | None = None

    @property
    def names(self) -> list[str]:
        return self.elements.names

    A = property(lambda self: self.terms.area_fraction)
    P = property(lambda self: self.terms.centre_closeness)
    D = property(lambda self: self.terms.distance)
    V = property(lambda self: self.terms.visibility)
    C = property(lambda self: self.terms.cost)
    R = property(lambda self: self.terms.relevance)
    S = property(lambda self: self.terms.previously_selected)
    K = property(lambda self: self.elements.priority)
    Q = property(lambda self: self.elements.rt_cost)

    def selected_names(self) -> frozenset[str]:
        """The selection as names: next frame's S."""
        return frozenset(compress(self.names, self.selected.tolist()))

    def columns(self, frame: int | None = None) -> dict[str, list]:
        """selection.csv as columns, in SELECTION_COLUMNS order (booleans as 0/1)."""
        frame = self.frame if frame is None else frame
        n = len(self.names)
        as_int = lambda array: np.asarray(array, dtype=np.int64).tolist()  # noqa: E731
        as_float = lambda array: np.asarray(array, dtype=np.float64).tolist()  # noqa: E731
        columns = {
            "frame": [frame] * n, "element": list(self.names), "visible": as_int(self.terms.visible),
            "A": as_float(self.A), "P": as_float(self.P), "D": as_float(self.D), "V": as_float(self.V),
            "Q": as_float(self.Q), "C": as_float(self.C), "K": as_float(self.K), "S": as_int(self.S),
            "R": as_float(self.R), "selected": as_int(self.selected), "reason": list(self.reason),
            "predicted_ms": as_float(self.predicted_ms),
        }
        if self.benefit_estimate is not None:
            columns["benefit"] = as_float(self.benefit_estimate)
            columns["effects"] = [";".join(effect for effect in sorted(self.effects) if self.effects[effect][i])
                                  for i in range(n)]
            if self.item_rate is not None:
                columns["rate"] = as_float(self.item_rate)
        elif self.terms.weighted_visibility is not None:
            columns["benefit"] = as_float(self.terms.weighted_visibility)
        return columns

    def rows(self, frame: int | None = None) -> list[dict]:
        """One dict per element with the keys of SELECTION_COLUMNS, in order, then ``predicted_ms``
        and, when there is one, ``benefit``: the normalised V x benefit that replaced V in R under
        the ``error`` relevance, or under the BENEFIT selection the element's summed item value
        with ``effects``, the effects traced (``;``-separated)."""
        columns = self.columns(frame)
        keys = SELECTION_COLUMNS + tuple(key for key in ("predicted_ms", "benefit", "effects", "rate")
                                         if key in columns)
        return [dict(zip(keys, values)) for values in zip(*(columns[key] for key in keys))]


def select(elements: FrameElements, previous_selection=None, settings: SelectionSettings | None = None,
           model: CostModel | None = None, *, time_left_ms: float | None = None,
           element_ms: np.ndarray | None = None, frame: int | None = None,
           raster_ms: float | None = None, choose: bool = True) -> SelectionResult:
    """Choose this frame's ray traced elements (sections V.B-V.D).

    ``previous_selection``: last frame's selection (see previously_selected_mask).
    ``model``: the cost model giving T and each element's predicted ms; a cold
    :class:`CostModel` when None.  ``time_left_ms`` and ``element_ms`` override
    the model's T and predicted ms (tests, replays).  ``raster_ms``: the recurring raster time
    this frame already spent, measured (T is the time left after it), else predicted.
    ``choose=False``: the terms and T only, for a caller that chooses itself (``BENEFIT``): no
    element's ms predicted (0), nothing selected, the selection graph not run.
    """
    settings = settings or SelectionSettings()
    model = model or CostModel()
    previously_selected = previously_selected_mask(elements.names, previous_selection)
    terms = element_terms(elements, previously_selected, settings.selection_weight, settings.max_area_fraction,
                          settings.relevance)

    if not choose and (settings.budget_at is None or time_left_ms is not None):
        predicted_ms = np.zeros(len(elements))
    elif element_ms is None:
        predicted_ms = model.predict_element_ms(elements, terms.cost, settings.cost_mode)
    else:
        predicted_ms = np.asarray(element_ms, dtype=np.float64)
        if predicted_ms.shape != (len(elements),):
            raise ValueError(f"element_ms has shape {predicted_ms.shape}, expected ({len(elements)},)")
        predicted_ms = clamp_finite(predicted_ms, nan=0.0, low=0.0, high=MAX_PREDICTED_MS)
    budget_ms = settings.budget_ms
    if settings.mode == "RASTER":
        time_left = 0.0
    elif time_left_ms is None and settings.budget_at is not None:
        # A fraction of the way to the ray traced frame: of the predicted time to trace every
        # visible candidate (RAYTRACE's selection), with the same non-trace stages.
        traced_by_raytrace = terms.candidate & terms.visible
        time_left = settings.budget_at * float(np.sum(predicted_ms[traced_by_raytrace]))
        time_left = float(clamp_finite(time_left, nan=0.0, low=0.0, high=MAX_PREDICTED_MS))
        budget_ms = float(min(model.non_trace_ms() + time_left, MAX_PREDICTED_MS))
    else:
        time_left = model.time_left(settings.budget_ms, raster_ms) if time_left_ms is None else time_left_ms
        time_left = float(clamp_finite(time_left, nan=0.0, low=0.0, high=MAX_PREDICTED_MS))

    # Tracing anything costs a fixed part first (reading the layers back, the moving objects'
    # BVH, the pixels' tiles), charged once when the model predicts the times.
    overhead = model.trace_overhead_ms() if time_left_ms is None and element_ms is None else 0.0
    n = len(elements)
    eligible = terms.candidate & terms.visible
    if settings.mode == "HYBRID":
        eligible &= terms.within_area
    selected = np.zeros(n, dtype=bool)
    if not choose:
        predicted_trace = 0.0
    elif settings.mode == "HYBRID":
        nodes = np.flatnonzero(eligible)
        graph = SelectionGraph(nodes, predicted_ms[nodes], terms.relevance[nodes], settings.order)
        # The elements share what is left of T after the fixed part.
        node_selected, predicted_trace = graph.select(max(time_left - overhead, 0.0))
        if np.any(node_selected):
            predicted_trace += overhead
        selected[nodes] = node_selected
    elif settings.mode == "RAYTRACE":
        selected = eligible.copy()
        predicted_trace = float(np.sum(predicted_ms[selected]))
        if np.any(selected):
            predicted_trace += overhead
    else:
        predicted_trace = 0.0

    return SelectionResult(
        elements=elements, terms=terms, selected=selected, reason=not_traced_reasons(terms, selected),
        predicted_ms=predicted_ms, predicted_trace_ms=float(min(predicted_trace, MAX_PREDICTED_MS)),
        time_left_ms=time_left, mode=settings.mode, cost_mode=settings.cost_mode,
        selection_weight=settings.selection_weight, frame=frame,
        budget_ms=budget_ms, relevance_mode=settings.relevance, order=settings.order,
    )


def not_traced_reasons(terms: ElementTerms, selected: np.ndarray) -> list[str]:
    """Each element's ``reason`` (selection.csv): empty when selected, else the first of
    not_candidate, not_visible, over_area that applies, else over_budget."""
    reason = np.full(len(selected), "over_budget", dtype=object)
    reason[~terms.within_area] = "over_area"
    reason[~terms.visible] = "not_visible"
    reason[~terms.candidate] = "not_candidate"
    reason[np.asarray(selected, bool)] = ""
    return reason.tolist()


def force_selection(result: SelectionResult, names) -> SelectionResult:
    """``result`` with its selection replaced by ``names`` (those visible and candidates):
    the oracle's hook (:mod:`.oracle`), which renders chosen subsets of a frame outside
    any timed region.  Terms, T and predictions stay; reasons follow the new selection
    (an element dropped gets ``over_budget`` or its own reason)."""
    chosen = {str(name) for name in names}
    terms = result.terms
    eligible = terms.candidate & terms.visible
    selected = eligible & np.fromiter((name in chosen for name in result.names), dtype=bool,
                                      count=len(result.names))
    return dataclass_replace(result, selected=selected, reason=not_traced_reasons(terms, selected),
                             predicted_trace_ms=float(min(np.sum(result.predicted_ms[selected]), MAX_PREDICTED_MS)))
