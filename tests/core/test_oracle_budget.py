"""One oracle per budget (phrt_addon/report/oracle.py): the nominal time for tracing from the raster
run's shared part, median costs, regret rows round-trip; offline rescoring of recorded choices
(phrt_addon/report/rescore.py) on the oracle's measurements.  Real RunLog and oracle files, no bpy."""
import numpy as np
import pytest

from phrt.phrt_addon.report import oracle, rescore
from phrt.phrt_addon.runs.run_log import RunLog


def test_the_shared_part_is_the_raster_runs_raster_select_and_composite_its_first_frame_the_steady_median():
    rows = [{"frame": 1, "raster_ms": 900.0, "composite_ms": 100.0, "select_ms": 80.0},
            {"frame": 2, "raster_ms": 30.0, "composite_ms": 10.0, "select_ms": 1.0},
            {"frame": 3, "raster_ms": 34.0, "composite_ms": None, "select_ms": 1.0},
            {"frame": 4, "raster_ms": 40.0, "composite_ms": 10.0, "select_ms": 1.0},
            {"frame": 5, "raster_ms": 40.0, "composite_ms": 10.0}]  # a row without select_ms: 0 for it
    shared = oracle.shared_ms(rows)
    assert shared[2] == pytest.approx(41.0) and shared[4] == pytest.approx(51.0) and shared[5] == pytest.approx(50.0)
    assert shared[1] == pytest.approx(50.0) and shared[3] == pytest.approx(50.0)
    assert oracle.nominal_time_left(120.0, 50.0) == pytest.approx(70.0)
    assert oracle.nominal_time_left(40.0, 50.0) == 0.0


def test_a_candidates_cost_is_the_median_of_its_timings():
    assert oracle.median_ms([12.0, 9.0, 30.0]) == (pytest.approx(12.0), pytest.approx(21.0))


def frame_candidates():
    return oracle.FrameCandidates(frame=4, names=["mirror", "glass", "fence"], cost_ms=np.array([10.0, 6.0, 2.0]),
                                  benefit=np.array([0.03, 0.01, 0.005]), flip_raster=0.10, overhead_ms=1.0,
                                  cost_spread_ms=np.array([1.0, 0.5, 0.2]))


def test_every_variant_at_a_budget_is_judged_against_one_capacity_not_its_own_time_left():
    frame = frame_candidates()
    chosen = frame.choose(oracle.nominal_time_left(60.0, 49.0))  # 11 ms: 1 fixed + the mirror (10)
    assert chosen == {"mirror"}
    thrifty = oracle.regret_row("a", 4, 60.0, 49.0, 3.0, {"fence"}, 0.095, chosen, 0.07, frame, oracle_trace_ms=11.5)
    lavish = oracle.regret_row("b", 4, 60.0, 49.0, 40.0, {"mirror", "glass"}, 0.06, chosen, 0.07, frame)
    assert thrifty["capacity_ms"] == lavish["capacity_ms"] == pytest.approx(11.0)
    assert lavish["regret"] == pytest.approx(-0.01)  # it overran: it may beat the oracle, and it shows
    assert thrifty["oracle_trace_ms"] == 11.5 and thrifty["oracle_cost_ms"] == pytest.approx(11.0)
    assert thrifty["raster_flip"] == pytest.approx(0.10)


def write_run(root, name, selected_by_frame, extra=None):
    run_dir = root / name
    log = RunLog(run_dir)
    for frame in (4, 8):
        rows = []
        for element in ("mirror", "glass", "fence"):
            selected = element in selected_by_frame[frame]
            rows.append({"frame": frame, "element": element, "visible": True, "A": 0.1, "P": 0.5, "D": 2.0, "V": 1.0,
                         "Q": 1.0, "C": 1.0, "K": 1.0, "S": 0, "R": 1.0, "selected": selected,
                         "reason": "" if selected else "over_budget", **(extra or {}).get(element, {})})
        log.add_frame({"frame": frame, "mode": "HYBRID", "total_ms": 60.0, "raster_ms": 40.0, "select_ms": 1.0,
                       "trace_ms": 10.0, "composite_ms": 9.0, "budget_ms": 60.0, "predicted_trace_ms": 10.0,
                       "n_candidates": 3, "n_visible": 3, "n_selected": len(selected_by_frame[frame]), "rays": 1},
                      rows)
    log.close({"scene": "s", "path": "p", "resolution": [8, 8], "blender_version": "5.0.1",
               "embreex_version": "4.4.0.post1"})
    return run_dir


def test_rescore_judges_recorded_choices_on_the_oracles_measurements(tmp_path):
    frames = []
    for number in (4, 8):
        frame = frame_candidates()
        frame.frame = number
        frames.append(frame)
    extra = {"mirror": {"predicted_ms": 5.0, "benefit": 0.9}, "glass": {"predicted_ms": 3.0, "benefit": 0.2},
             "fence": {"predicted_ms": 1.0, "benefit": 0.1}}
    best = write_run(tmp_path, "best", {4: {"mirror"}, 8: {"mirror"}}, extra)
    cheap = write_run(tmp_path, "cheap", {4: {"fence"}, 8: {"glass", "fence"}})
    rows = []
    # The best run kept 10 ms for tracing (the nominal 13 less its bookkeeping), the cheap one 20.
    for run, picks, own_ms in ((best, ({"mirror"}, {"mirror"}), 10.0), (cheap, ({"fence"}, {"glass", "fence"}), 20.0)):
        for frame, pick in zip(frames, picks):
            rows.append(oracle.regret_row(run.name, frame.frame, 60.0, 47.0, own_ms, pick, 0.08, {"mirror"}, 0.07,
                                          frame))
    oracle.write_results(tmp_path / oracle.ORACLE_DIR, 4, [4, 8], frames, rows, {"best": best, "cheap": cheap})
    scored, folder = rescore.rescore(tmp_path)
    by_run = {row["run"]: row for row in scored}
    assert by_run["best"]["captured_additive"] == pytest.approx(1.0)
    assert by_run["cheap"]["captured_additive"] == pytest.approx((0.005 + 0.015) / 0.06)
    assert by_run["best"]["over_capacity_frames"] == 0
    # In 10 ms (1 fixed) the best subset is glass and fence (0.015 of the mirror's 0.03); in 20 the
    # three (0.045): the time a run kept bounds what any choice of it could capture.
    assert by_run["best"]["own_time_additive"] == pytest.approx(0.5)
    assert by_run["cheap"]["own_time_additive"] == pytest.approx(0.045 / 0.03)
    # A judged frame without its time left: no own-time share rather than 0 ms of it.
    rows = [dict(row, time_left_ms=None) if row["run"] == "cheap" and row["frame"] == 8 else row for row in rows]
    oracle.write_results(tmp_path / oracle.ORACLE_DIR, 4, [4, 8], frames, rows, {"best": best, "cheap": cheap})
    by_run = {row["run"]: row for row in rescore.rescore(tmp_path)[0]}
    assert by_run["cheap"]["own_time_additive"] is None and by_run["best"]["own_time_additive"] == pytest.approx(0.5)
    assert by_run["best"]["median_predicted_over_measured"] == pytest.approx(5.0 / 11.0)
    assert by_run["cheap"]["median_predicted_over_measured"] is None  # no predicted_ms recorded
    assert by_run["best"]["benefit_rank_correlation"] == pytest.approx(1.0)
    assert (folder / rescore.RESCORE_CSV).is_file() and "best" in (folder / rescore.RESCORE_MD).read_text()
    with pytest.raises(ValueError, match="no complete oracle"):
        rescore.rescore(tmp_path / "elsewhere")
