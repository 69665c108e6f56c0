"""Test-only analysis of a selection: the hysteresis margin (see "Hysteresis margin" in
``phrt_addon/select/heuristic.py``'s docstring).  Kept out of the shipped core: nothing renders with it."""
import numpy as np

from phrt.phrt_addon.select.heuristic import UNBOUNDED_MARGIN, SelectionGraph, SelectionResult


def hysteresis_margin(result: SelectionResult) -> np.ndarray:
    """Per element, how much its V may change and leave its state unchanged.

    See "Hysteresis margin" in the module docstring.  Defined for HYBRID
    results; ``UNBOUNDED_MARGIN`` where no element of the other state can be
    crossed (non-competing elements, K = 0, no rival on the relevant side).
    Assumes the element's cost and the frame's visibility scale stay as they
    are (V changed through D, the element not the frame's most visible).
    """
    n = len(result.names)
    margin = np.full(n, UNBOUNDED_MARGIN)
    competing = result.terms.candidate & result.terms.visible & result.terms.within_area
    nodes = np.flatnonzero(competing)
    if len(nodes) == 0 or result.mode != "HYBRID":
        return margin
    graph = SelectionGraph(nodes, result.predicted_ms[nodes], result.R[nodes])
    ordered = nodes[graph.relevance_order]
    relevance = result.R[ordered]
    chosen = result.selected[ordered]
    priority = result.K[ordered]
    positions = np.arange(len(ordered))
    unselected_positions = positions[~chosen]
    selected_positions = positions[chosen]
    gap = np.full(len(ordered), np.inf)
    # Selected: the first unselected node after it has the highest relevance below.
    after = np.searchsorted(unselected_positions, positions, side="right")
    has_below = chosen & (after < len(unselected_positions))
    below = unselected_positions[np.minimum(after, max(len(unselected_positions) - 1, 0))] if len(
        unselected_positions) else positions
    gap[has_below] = relevance[has_below] - relevance[below[has_below]]
    # Unselected: the last selected node before it has the lowest relevance above.
    before = np.searchsorted(selected_positions, positions, side="left") - 1
    has_above = ~chosen & (before >= 0)
    above = selected_positions[np.maximum(before, 0)] if len(selected_positions) else positions
    gap[has_above] = relevance[above[has_above]] - relevance[has_above]
    with np.errstate(divide="ignore", invalid="ignore"):
        in_visibility = np.where(priority > 0, gap / priority, np.inf)
    margin[ordered] = np.where(np.isfinite(in_visibility), in_visibility, UNBOUNDED_MARGIN)
    return margin
