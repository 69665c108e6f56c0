"""Selection heuristic: the paper's equations, node selection, modes, logs and
properties on random scenes (hypothesis).  No bpy."""
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings, strategies as st

from phrt.phrt_addon import defaults
from phrt.phrt_addon.select import heuristic, selection_terms
from phrt.phrt_addon import schema
from phrt.phrt_addon.runs import run_log
from phrt.phrt_addon.runs import summary as run_summary
from phrt.phrt_addon.select.cost_model import CostModel
from phrt.phrt_addon.select.heuristic import select
from phrt.phrt_addon.select.selection_terms import FrameElements, SelectionSettings

from hysteresis import hysteresis_margin

FRAME_PX = 1000
PROPERTY_SETTINGS = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def frame(n, **fields):
    """A frame of n visible candidates at the centre (override any field)."""
    base = dict(names=[f"e{i}" for i in range(n)], area_px=np.full(n, 10), frame_px=FRAME_PX,
                centre_ndc=np.zeros((n, 2)), distance=np.ones(n))
    base.update(fields)
    return FrameElements(**base)


def quick_model():
    """A cold cost model whose raster, select and composite priors leave most
    of a small budget to ray tracing."""
    return CostModel(stage_prior_ms={"raster": 1.0, "select": 0.1, "composite": 0.4})


def hybrid(**fields):
    return SelectionSettings(mode="HYBRID", **fields)


def all_finite(result):
    arrays = [result.A, result.P, result.D, result.V, result.C, result.R, result.S, result.K, result.Q,
              result.predicted_ms]
    scalars = [result.predicted_trace_ms, result.time_left_ms, result.terms.visibility_scale]
    return all(np.all(np.isfinite(np.asarray(array, dtype=np.float64))) for array in arrays) and all(
        np.isfinite(scalar) for scalar in scalars)


# -- the paper's terms, hand computed ----------------------------------------

def test_equations_on_a_hand_computed_frame():
    elements = FrameElements(
        names=["a", "b", "c"], area_px=np.array([100, 0, 200]), frame_px=1000,
        centre_ndc=np.array([[0.0, 0.0], [0.0, 0.0], [0.5, -0.25]]), distance=np.array([2.0, 1.0, 0.5]),
        priority=np.array([3.0, 1.0, 1.0]), rt_cost=np.array([2.0, 1.0, 1.0]))
    result = select(elements, {"a"}, hybrid(selection_weight=0.5), time_left_ms=1e6,
                    element_ms=np.zeros(3))
    # A = pixels / frame pixels
    np.testing.assert_allclose(result.A, [0.1, 0.0, 0.2])
    # P = 1 - max(|x|, |y|); 0 for the invisible element
    np.testing.assert_allclose(result.P, [1.0, 0.0, 0.5])
    np.testing.assert_allclose(result.D, [2.0, 1.0, 0.5])
    # raw A*P/D: a 0.05, c 0.2 (the scale) -> V normalised by 0.2
    assert result.terms.visibility_scale == pytest.approx(0.2)
    np.testing.assert_allclose(result.V, [0.25, 0.0, 1.0])
    # C = V * Q
    np.testing.assert_allclose(result.C, [0.5, 0.0, 1.0])
    # R = (S * I + V) * K: a was selected last frame
    np.testing.assert_array_equal(result.S, [True, False, False])
    np.testing.assert_allclose(result.R, [(0.5 + 0.25) * 3.0, 0.0, 1.0])
    assert result.reason == ["", "not_visible", ""]


@pytest.mark.parametrize("depth", [0.0, 1e-9, -4.0, float("nan"), float("-inf")])
def test_distance_touching_or_behind_the_camera_is_clamped_to_the_near_plane(depth):
    result = select(frame(1, distance=np.array([depth]), near_clip=0.25), None, hybrid(), time_left_ms=10,
                    element_ms=np.ones(1))
    assert result.D[0] == 0.25
    assert all_finite(result)


def test_default_near_plane_is_blenders_clip_start():
    result = select(frame(1, distance=np.array([0.0])), None, hybrid(), time_left_ms=10, element_ms=np.ones(1))
    assert result.D[0] == selection_terms.NEAR_CLIP_DISTANCE == 0.1


def test_far_distance_keeps_visibility_finite_and_ranks_last():
    elements = frame(3, distance=np.array([1e9, 1.0, 2.0]))
    result = select(elements, None, hybrid(), time_left_ms=10, element_ms=np.ones(3))
    assert result.D[0] == 1e9
    assert 0 < result.V[0] < 1e-8
    assert list(np.argsort(-result.R)) == [1, 2, 0]


@pytest.mark.parametrize("centre, closeness", [((0.0, 0.0), 1.0), ((0.5, -0.25), 0.5), ((-0.2, 0.8), 0.2),
                                               ((1.0, 0.0), 0.0), ((0.0, -1.0), 0.0), ((1.5, 3.0), 0.0),
                                               ((float("nan"), 0.0), 0.0)])
def test_centre_closeness_is_one_at_the_centre_and_zero_at_the_edge(centre, closeness):
    result = select(frame(1, centre_ndc=np.array([centre])), None, hybrid(), time_left_ms=0, element_ms=np.ones(1))
    assert result.P[0] == pytest.approx(closeness)


def test_visibility_is_normalised_to_the_most_visible_competing_candidate():
    # The over-area element and the non-candidate do not set the scale.
    elements = frame(4, area_px=np.array([100, 50, 900, 400]), candidate=np.array([True, True, True, False]))
    result = select(elements, None, hybrid(), time_left_ms=10, element_ms=np.ones(4))
    np.testing.assert_allclose(result.V, [1.0, 0.5, 9.0, 4.0])
    assert result.reason == ["", "", "over_area", "not_candidate"]


# -- node selection ----------------------------------------------------------

def test_figure_7_equal_costs_budget_fits_all_but_four_the_four_least_relevant_are_left_out():
    """Like the paper's Figure 7 (a green sphere and three octahedrons rastered)."""
    n = 10
    rng = np.random.default_rng(7)
    distance = rng.permutation(np.arange(1.0, n + 1))  # relevance falls with distance
    elements = frame(n, area_px=np.full(n, 40), distance=distance, reflections=np.ones(n, bool),
                     rays_per_pixel=np.full(n, 2.0))
    model = CostModel()
    cost = model.predict_element_ms(elements, np.ones(n), "measured")
    assert np.all(cost == cost[0]) and cost[0] > 0  # equal cost through the real model
    result = select(elements, None, hybrid(), model, time_left_ms=6.5 * cost[0])
    least_relevant = set(np.argsort(result.R)[:4].tolist())
    assert set(np.flatnonzero(~result.selected).tolist()) == least_relevant
    assert least_relevant == set(np.flatnonzero(distance > 6).tolist())
    assert [result.reason[i] for i in sorted(least_relevant)] == ["over_budget"] * 4
    assert result.predicted_trace_ms == pytest.approx(6 * cost[0])


def test_a_less_relevant_cheap_node_fills_the_time_an_expensive_one_cannot_use():
    elements = frame(3, distance=np.array([1.0, 2.0, 3.0]))
    result = select(elements, None, hybrid(), time_left_ms=10, element_ms=np.array([6.0, 5.0, 4.0]))
    assert result.selected.tolist() == [True, False, True]
    assert result.predicted_trace_ms == 10.0


def test_the_greedy_pass_goes_on_past_a_node_that_does_not_fit():
    elements = frame(5, distance=np.arange(1.0, 6.0))
    result = select(elements, None, hybrid(), time_left_ms=9, element_ms=np.array([3.0, 20.0, 3.0, 3.0, 1.0]))
    assert result.selected.tolist() == [True, False, True, True, False]


def test_selection_graph_edges_follow_the_paper():
    graph = heuristic.SelectionGraph(np.array([4, 7, 9]), np.array([2.0, 5.0, 1.0]), np.array([0.3, 0.1, 0.9]))
    assert graph.cost_edges().tolist() == [[7, 4], [4, 9]]  # each node -> the next cheaper one
    edges = {tuple(edge) for edge in graph.relevance_edges().tolist()}
    assert edges == {(4, 9), (7, 4), (7, 9)}  # each node -> every node of higher relevance


def test_relevance_edges_refuse_a_large_graph():
    n = heuristic.MAX_DEBUG_EDGE_NODES + 1
    graph = heuristic.SelectionGraph(np.arange(n), np.ones(n), np.ones(n))
    with pytest.raises(ValueError, match="O\\(n\\^2\\)"):
        graph.relevance_edges()


def test_selected_last_frame_keeps_its_place_within_the_selection_weight():
    """Two elements of equal K and cost, time for one: the one selected last frame
    keeps its place while the rival's V exceeds its own by less than I."""
    def run(rival_visibility, selection_weight):
        elements = frame(2, area_px=np.array([100, 100]),
                         distance=np.array([1.0, 1.0 / rival_visibility]))  # V = 1 and rival_visibility
        return select(elements, {"e0"}, hybrid(selection_weight=selection_weight), time_left_ms=1,
                      element_ms=np.ones(2))
    # Rival twice as visible: V 1 -> rival normalises to 1, e0 to 0.5: a gap of 0.5.
    assert run(2.0, 0.6).selected.tolist() == [True, False]
    assert run(2.0, 0.4).selected.tolist() == [False, True]
    assert run(2.0, 0.0).selected.tolist() == [False, True]


def test_hysteresis_margin_is_the_relevance_gap_to_the_other_state_and_is_tight():
    """e0 (V 0.5, selected last frame, I = 0.6) against e1 (V 1): R 1.1 and 1.0,
    time for one.  Both margins are 0.1 of V; crossing it flips the decision."""
    def run(e0_distance, previous):
        elements = frame(2, area_px=np.array([100, 100]), distance=np.array([e0_distance, 1.0]))
        return select(elements, previous, hybrid(selection_weight=0.6), time_left_ms=1, element_ms=np.ones(2))
    steady = run(2.0, {"e0"})
    assert steady.selected.tolist() == [True, False] and steady.S.tolist() == [True, False]
    np.testing.assert_allclose(hysteresis_margin(steady), [0.1, 0.1])
    assert run(1 / 0.41, steady).selected.tolist() == [True, False]  # V 0.5 -> 0.41: kept
    assert run(1 / 0.39, steady).selected.tolist() == [False, True]  # V 0.5 -> 0.39: lost


def test_previous_selection_is_keyed_by_name_so_elements_may_come_and_go():
    elements = frame(3, names=["new", "kept", "other"])
    previous = {"kept": True, "gone": True, "other": False}
    result = select(elements, previous, hybrid(), time_left_ms=0, element_ms=np.ones(3))
    assert result.S.tolist() == [False, True, False]
    again = select(elements, result, hybrid(), time_left_ms=10, element_ms=np.ones(3))
    assert again.S.tolist() == [False, False, False]  # nothing fitted in T = 0
    assert select(elements, again, hybrid(), time_left_ms=10, element_ms=np.ones(3)).S.tolist() == [True] * 3


# -- modes, reasons, logs ----------------------------------------------------

def test_reasons_in_hybrid_mode():
    elements = frame(5, area_px=np.array([10, 0, 500, 10, 10]), candidate=np.array([True, True, True, False, True]),
                     distance=np.array([1.0, 1.0, 1.0, 1.0, 2.0]))
    result = select(elements, None, hybrid(), time_left_ms=1, element_ms=np.ones(5))
    assert result.reason == ["", "not_visible", "over_area", "not_candidate", "over_budget"]
    assert result.selected.tolist() == [True, False, False, False, False]


def test_raytrace_mode_selects_every_visible_candidate_with_no_budget_and_no_area_limit():
    elements = frame(4, area_px=np.array([10, 0, 1000, 10]), candidate=np.array([True, True, True, False]))
    result = select(elements, None, SelectionSettings(mode="raytrace"), time_left_ms=0, element_ms=np.full(4, 50.0))
    assert result.selected.tolist() == [True, False, True, False]
    assert result.reason == ["", "not_visible", "", "not_candidate"]
    assert result.predicted_trace_ms == 100.0


def test_raster_mode_selects_nothing_as_a_zero_ray_tracing_time():
    elements = frame(4, area_px=np.array([10, 0, 1000, 10]), candidate=np.array([True, True, True, False]))
    result = select(elements, None, SelectionSettings(mode="RASTER"), time_left_ms=1e6, element_ms=np.zeros(4))
    assert not result.selected.any()
    assert result.time_left_ms == 0.0
    assert result.reason == ["over_budget", "not_visible", "over_area", "not_candidate"]


def test_unknown_mode_is_refused():
    with pytest.raises(ValueError, match="mode"):
        SelectionSettings(mode="PATHTRACE")


@pytest.mark.parametrize("field, value", [("budget_ms", -1.0), ("selection_weight", float("nan"))])
def test_nonsense_settings_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        SelectionSettings(**{field: value})


def test_paper_and_measured_cost_modes_both_work_in_either_case():
    elements = frame(2, area_px=np.array([100, 50]), reflections=np.array([True, True]))
    paper = select(elements, None, SelectionSettings(cost_mode="PAPER"), time_left_ms=1e6)
    measured = select(elements, None, SelectionSettings(cost_mode="measured"), time_left_ms=1e6)
    assert paper.cost_mode == "paper" and measured.cost_mode == "measured"
    np.testing.assert_allclose(paper.predicted_ms / paper.predicted_ms[0], paper.C / paper.C[0])
    np.testing.assert_allclose(measured.predicted_ms / measured.predicted_ms[0], [1.0, 0.5])


def test_rows_have_the_contract_columns_in_order():
    elements = frame(2, area_px=np.array([10, 0]))
    result = select(elements, ["e1"], hybrid(), time_left_ms=5, element_ms=np.ones(2))
    rows = result.rows(frame=12)
    # The contract's columns in order, then the item's predicted cost (the next round's names).
    assert [list(row) for row in rows] == [list(schema.SELECTION_COLUMNS) + ["predicted_ms"]] * 2
    assert schema.SELECTION_COLUMNS == ("frame", "element", "visible", "A", "P", "D", "V", "Q", "C", "K", "S",
                                           "R", "selected", "reason")
    assert rows[0] == {"frame": 12, "element": "e0", "visible": 1, "A": 0.01, "P": 1.0, "D": 1.0, "V": 1.0,
                       "Q": 1.0, "C": 1.0, "K": 1.0, "S": 0, "R": 1.0, "selected": 1, "reason": "",
                       "predicted_ms": 1.0}
    assert rows[1]["S"] == 1 and rows[1]["R"] == 0.5 and rows[1]["reason"] == "not_visible"
    assert result.columns(frame=12)["reason"] == ["", "not_visible"]


def test_selection_flips_of_results_are_counted_per_100_frames_by_the_one_rule():
    elements = frame(1)
    on = select(elements, None, hybrid(), time_left_ms=1, element_ms=np.ones(1))
    off = select(elements, None, hybrid(), time_left_ms=0, element_ms=np.ones(1))
    rows = [row for number, result in enumerate([on, off, on, off], 1) for row in result.rows(number)]
    assert run_summary.flips_per_element_per_100(rows) == {"e0": 75.0}  # 3 flips in 4 frames


def test_mismatched_array_lengths_are_refused_with_the_field_name():
    with pytest.raises(ValueError, match="distance"):
        frame(3, distance=np.ones(2))
    with pytest.raises(ValueError, match="unique"):
        frame(2, names=["x", "x"])


# -- extreme inputs ----------------------------------------------------------

def test_area_zero_is_not_visible_and_area_one_is_over_area():
    elements = frame(2, area_px=np.array([0, FRAME_PX]))
    result = select(elements, None, hybrid(), time_left_ms=1e6, element_ms=np.ones(2))
    assert result.A.tolist() == [0.0, 1.0]
    assert result.reason == ["not_visible", "over_area"]
    assert select(elements, None, SelectionSettings(mode="RAYTRACE")).selected.tolist() == [False, True]


def test_area_exactly_at_the_limit_is_allowed():
    elements = frame(1, area_px=np.array([int(defaults.MAX_AREA_FRACTION * FRAME_PX)]))
    assert select(elements, None, hybrid(), time_left_ms=1, element_ms=np.ones(1)).selected[0]


def test_priority_zero_is_never_traced_and_huge_priority_comes_first():
    elements = frame(3, priority=np.array([0.0, 1e12, 1.0]), distance=np.array([1.0, 1e9, 1.0]))
    result = select(elements, None, hybrid(), time_left_ms=1, element_ms=np.ones(3))
    assert result.reason == ["not_candidate", "", "over_budget"]
    raytraced = select(elements, None, SelectionSettings(mode="RAYTRACE"), element_ms=np.ones(3))
    assert raytraced.selected.tolist() == [False, True, True]
    assert all_finite(result)


def test_zero_budget_selects_only_what_is_predicted_free():
    elements = frame(3)
    result = select(elements, None, hybrid(budget_ms=0.0), element_ms=np.array([1.0, 0.0, 1e-9]))
    assert result.time_left_ms == 0.0
    assert result.selected.tolist() == [False, True, False]


def test_budget_larger_than_everything_selects_every_eligible_element():
    elements = frame(4, area_px=np.array([10, 10, 900, 10]), reflections=np.ones(4, bool))
    result = select(elements, None, hybrid(budget_ms=1e300))
    assert result.selected.tolist() == [True, True, False, True]
    assert np.isfinite(result.time_left_ms)


def test_no_elements_at_all():
    result = select(frame(0), None, hybrid())
    assert result.rows(1) == [] and result.predicted_trace_ms == 0.0 and all_finite(result)


def test_one_element():
    result = select(frame(1), None, hybrid(), time_left_ms=1, element_ms=np.ones(1))
    assert result.selected.tolist() == [True]


def test_identical_candidates_tie_deterministically_by_element_order():
    elements = frame(10)
    first = select(elements, None, hybrid(), time_left_ms=4, element_ms=np.ones(10))
    assert np.flatnonzero(first.selected).tolist() == [0, 1, 2, 3]
    again = select(frame(10), None, hybrid(), time_left_ms=4, element_ms=np.ones(10))
    assert again.rows(0) == first.rows(0)


def test_a_hundred_thousand_candidates_take_no_python_loop_per_candidate():
    """Counted, not timed: the Python function calls (and generator steps) made while selecting
    among 100,000 candidates are one per candidate for the lookup of last frame's names and a
    few hundred more (whole-array numpy work otherwise: no per-candidate Python function)."""
    n = 100_000
    rng = np.random.default_rng(3)
    elements = FrameElements(names=[f"e{i}" for i in range(n)], area_px=rng.integers(0, 30, n),
                             frame_px=640 * 480, centre_ndc=rng.uniform(-1, 1, (n, 2)),
                             distance=rng.uniform(-1, 100, n), reflections=rng.random(n) < 0.5,
                             shadows=rng.random(n) < 0.5, rays_per_pixel=rng.uniform(0, 4, n))
    calls = [0]

    def count(frame, event, arg):
        if event == "call":
            calls[0] += 1

    previous = sys.getprofile()
    sys.setprofile(count)
    try:
        result = select(elements, set(elements.names[::3]), hybrid(budget_ms=150.0), CostModel())
    finally:
        sys.setprofile(previous)
    assert calls[0] < n + 1000, calls[0]
    assert 0 < result.selected.sum() < n
    assert result.predicted_trace_ms <= result.time_left_ms
    assert all_finite(result)


# -- properties on random scenes ---------------------------------------------

SPECIAL_DISTANCES = np.array([0.0, 1e-9, 1e9, -2.0, 0.1])
NON_FINITE = np.array([np.nan, np.inf, -np.inf])


def _sprinkle(rng, values, specials, share):
    """Replace a share of values by special values (extremes, NaN, inf)."""
    mask = rng.random(values.shape) < share
    return np.where(mask, rng.choice(specials, size=values.shape), values)


@st.composite
def scenes(draw, max_n=25, extreme=False):
    """Random scenes: hypothesis draws the size, a seed and the mix of special
    values; numpy draws the arrays (fast, and shrinks to small scenes)."""
    n = draw(st.integers(0, max_n))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    special_share = draw(st.sampled_from([0.0, 0.2, 0.6]))
    area = rng.integers(0, FRAME_PX // 2, n)
    area = _sprinkle(rng, area, np.array([0, 1, FRAME_PX // 2, FRAME_PX]), special_share)
    distance = _sprinkle(rng, rng.uniform(0.05, 100.0, n), SPECIAL_DISTANCES, special_share)
    priority = _sprinkle(rng, rng.uniform(0.01, 10.0, n), np.array([0.0, 1e12]), special_share)
    rt_cost = rng.uniform(0.1, 4.0, n)
    centre = rng.uniform(-1.0, 1.0, (n, 2))
    rays = rng.uniform(0.0, 6.0, n)
    if extreme:
        distance, priority, rt_cost, rays = (_sprinkle(rng, values, NON_FINITE, 0.2)
                                             for values in (distance, priority, rt_cost, rays))
        rt_cost = _sprinkle(rng, rt_cost, np.array([0.0, 1e12, -1.0]), 0.2)
        centre = _sprinkle(rng, centre, np.concatenate([NON_FINITE, [1e300, -5.0]]), 0.2)
    flags = rng.random((4, n)) < draw(st.sampled_from([0.2, 0.5, 0.9]))
    return dict(names=[f"e{i}" for i in range(n)], area_px=area.astype(np.int64), frame_px=FRAME_PX,
                candidate=flags[0], shadows=flags[1], reflections=flags[2], refractions=flags[3],
                centre_ndc=centre, distance=distance, priority=priority, rt_cost=rt_cost, rays_per_pixel=rays)


def previous_of(draw, n):
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    return {f"e{i}" for i in np.flatnonzero(rng.random(n) < 0.5)}


@PROPERTY_SETTINGS
@given(scenes(), st.data(), st.floats(0.0, 200.0), st.floats(0.0, 2.0), st.sampled_from(["paper", "MEASURED"]))
def test_predicted_cost_of_the_selection_never_exceeds_the_time_left(scene, data, budget, weight, cost_mode):
    elements = FrameElements(**scene)
    settings_ = hybrid(budget_ms=budget, selection_weight=weight, cost_mode=cost_mode)
    result = select(elements, previous_of(data.draw, len(elements)), settings_, quick_model())
    assert result.predicted_trace_ms <= result.time_left_ms
    assert np.sum(result.predicted_ms[result.selected]) == pytest.approx(result.predicted_trace_ms, rel=1e-9)


@PROPERTY_SETTINGS
@given(scenes(), st.data(), st.floats(0.0, 60.0), st.floats(0.0, 2.0), st.sampled_from(["paper", "measured"]))
def test_raising_an_elements_priority_never_removes_it_from_the_selection(scene, data, budget, weight, cost_mode):
    elements = FrameElements(**scene)
    previous = previous_of(data.draw, len(elements))
    settings_ = hybrid(budget_ms=budget, selection_weight=weight, cost_mode=cost_mode)
    before = select(elements, previous, settings_, quick_model())
    assume(before.selected.any())
    index = data.draw(st.sampled_from(np.flatnonzero(before.selected).tolist()))
    raised = dict(scene, priority=scene["priority"].copy())
    raised["priority"][index] = raised["priority"][index] * data.draw(st.floats(1.0, 1e6)) + data.draw(
        st.floats(0.0, 100.0))
    after = select(FrameElements(**raised), previous, settings_, quick_model())
    assert after.selected[index]


@PROPERTY_SETTINGS
@given(scenes(), st.data(), st.floats(0.0, 1e4), st.floats(0.0, 1.0))
def test_an_element_over_the_area_limit_is_never_selected(scene, data, budget, max_area):
    elements = FrameElements(**scene)
    result = select(elements, previous_of(data.draw, len(elements)),
                    hybrid(budget_ms=budget, max_area_fraction=max_area), quick_model())
    over = result.A > max_area
    assert not np.any(result.selected & over)
    assert all(result.reason[i] in ("over_area", "not_visible", "not_candidate") for i in np.flatnonzero(over))


def steady_selection(elements, settings_, element_ms, time_left_ms, rounds=20):
    """Repeat a frame until the selection is its own previous selection."""
    result = select(elements, None, settings_, time_left_ms=time_left_ms, element_ms=element_ms)
    for _ in range(rounds):
        again = select(elements, result, settings_, time_left_ms=time_left_ms, element_ms=element_ms)
        if np.array_equal(again.selected, result.selected) and np.array_equal(again.S, result.selected):
            return again
        result = again
    return None


@st.composite
def competing_scenes(draw):
    """Scenes where every element competes (visible candidates within the area
    limit), with fixed integer costs in ms and a time left."""
    n = draw(st.integers(2, 20))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    scene = dict(names=[f"e{i}" for i in range(n)], area_px=rng.integers(1, int(0.4 * FRAME_PX), n),
                 frame_px=FRAME_PX, centre_ndc=rng.uniform(-0.95, 0.95, (n, 2)), distance=rng.uniform(0.5, 50.0, n),
                 priority=rng.choice([0.5, 1.0, 1.0, 2.0, 5.0], n))
    return scene, rng.integers(0, 20, n).astype(np.float64), float(rng.integers(0, 60))


@PROPERTY_SETTINGS
@given(competing_scenes(), st.data(), st.floats(0.01, 2.0))
def test_an_element_whose_visibility_changes_by_less_than_its_hysteresis_margin_keeps_its_state(
        competing_scene, data, weight):
    """See "Hysteresis margin" in heuristic's docstring.  At a steady selection
    (the frame repeated until it is its own previous selection), one element's V
    moves through its distance D only; its cost stays (the measured mode's cost
    does not depend on D) and it is not the frame's most visible element (the
    visibility scale stays)."""
    scene, element_ms, time_left = competing_scene
    settings_ = hybrid(selection_weight=weight)
    steady = steady_selection(FrameElements(**scene), settings_, element_ms, time_left)
    assume(steady is not None)
    margin = hysteresis_margin(steady)
    movable = [index for index in range(len(steady.names))
               if 0 < steady.V[index] < np.max(np.delete(steady.V, index)) and margin[index] > 0]
    assume(movable)
    index = data.draw(st.sampled_from(movable))
    visibility = steady.V[index]
    room = np.max(np.delete(steady.V, index)) - visibility
    change = data.draw(st.floats(-1.0, 1.0)) * 0.5 * min(margin[index], visibility, room)
    new_distance = steady.A[index] * steady.P[index] / ((visibility + change) * steady.terms.visibility_scale)
    assume(new_distance > selection_terms.NEAR_CLIP_DISTANCE * 1.001)
    moved = dict(scene, distance=scene["distance"].copy())
    moved["distance"][index] = new_distance
    after = select(FrameElements(**moved), steady, settings_, time_left_ms=time_left, element_ms=element_ms)
    assert after.V[index] == pytest.approx(visibility + change, rel=1e-9)
    assert after.selected[index] == steady.selected[index]


@PROPERTY_SETTINGS
@given(scenes(), st.data(), st.floats(0.0, 300.0), st.sampled_from(["paper", "measured"]),
       st.sampled_from(schema.MODES))
def test_equal_input_gives_equal_output(scene, data, budget, cost_mode, mode):
    previous = previous_of(data.draw, len(scene["names"]))
    settings_ = SelectionSettings(budget_ms=budget, cost_mode=cost_mode, mode=mode)
    first = select(FrameElements(**{k: (v.copy() if isinstance(v, np.ndarray) else v) for k, v in scene.items()}),
                   set(previous), settings_, quick_model())
    second = select(FrameElements(**scene), set(previous), settings_, quick_model())
    assert first.rows(5) == second.rows(5)
    assert np.array_equal(first.selected, second.selected)
    assert first.predicted_trace_ms == second.predicted_trace_ms


@PROPERTY_SETTINGS
@given(scenes(extreme=True), st.data(), st.one_of(st.floats(0.0, 1e300), st.just(float("inf"))),
       st.floats(0.0, 1e6), st.sampled_from(["paper", "measured"]), st.sampled_from(schema.MODES))
def test_no_nan_or_inf_anywhere_even_from_extreme_input(scene, data, budget, weight, cost_mode, mode):
    elements = FrameElements(**scene)
    result = select(elements, previous_of(data.draw, len(elements)),
                    SelectionSettings(budget_ms=budget, selection_weight=weight, cost_mode=cost_mode, mode=mode),
                    quick_model())
    assert all_finite(result)
    for row in result.rows(0):
        assert all(np.isfinite(value) for value in row.values() if isinstance(value, float))
    margin = hysteresis_margin(result)
    assert np.all(np.isfinite(margin)) and np.all(margin >= 0)


def test_without_choosing_the_terms_and_t_are_the_same_and_nothing_is_selected():
    """``choose=False`` (the BENEFIT selection chooses its items itself): the paper's terms and T as
    when it chooses, no element's ms predicted, nothing selected, the graph not run."""
    elements = frame(4, area_px=np.array([10, 40, 5, 20]))
    chosen = select(elements, None, hybrid(budget_ms=30.0), quick_model())
    terms_only = select(elements, None, hybrid(budget_ms=30.0), quick_model(), choose=False)
    assert chosen.selected.any() and not terms_only.selected.any()
    assert terms_only.time_left_ms == chosen.time_left_ms and terms_only.predicted_trace_ms == 0.0
    assert np.array_equal(terms_only.R, chosen.R) and np.array_equal(terms_only.V, chosen.V)
    assert not terms_only.predicted_ms.any() and all_finite(terms_only)
