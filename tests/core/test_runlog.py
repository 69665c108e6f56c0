"""RunLog writes CONTRACT section 4's frames.csv, selection.csv and summary.json."""
import csv
import json
import math
import os

import numpy as np
import pytest

from phrt.phrt_addon.runs import run_log
from phrt.phrt_addon import schema
from phrt.phrt_addon.runs import run_files
from phrt.phrt_addon.runs.run_log import RunLog
from phrt.phrt_addon.runs import summary as run_summary

CALLER_SUMMARY = {"scene": "atrium", "path": "path1", "mode": "HYBRID",
                  "resolution": (64, 48), "budget_ms": 150.0,
                  "blender_version": "5.0.1", "embreex_version": "4.4.0.post1"}


def frame_row(frame, total_ms=100.0, **overrides):
    row = {"frame": frame, "mode": "HYBRID", "total_ms": total_ms, "raster_ms": 20.0,
           "select_ms": 1.0, "trace_ms": 70.0, "composite_ms": 9.0, "budget_ms": 150.0,
           "predicted_trace_ms": 65.0, "n_candidates": 3, "n_visible": 2, "n_selected": 1,
           "rays": 120000}
    row.update(overrides)
    return row


def selection_row(frame, element, selected, **overrides):
    row = {"frame": frame, "element": element, "visible": True, "A": 0.1, "P": 0.8, "D": 3.0,
           "V": 0.0266667, "Q": 1.0, "C": 0.0266667, "K": 1.0, "S": 0, "R": 0.0266667,
           "selected": selected, "reason": "" if selected else "over_budget"}
    row.update(overrides)
    return row


def header(path):
    with open(path, newline="") as handle:
        return next(csv.reader(handle))


def test_csv_headers_are_the_contract_columns_then_extras(tmp_path):
    with RunLog(tmp_path) as log:
        log.add_frame(frame_row(1, shadow_rays=5), [selection_row(1, "Sphere", True, area_px=12)])
    assert header(tmp_path / "frames.csv") == list(schema.FRAME_COLUMNS) + ["shadow_rays"]
    assert header(tmp_path / "selection.csv") == list(schema.SELECTION_COLUMNS) + ["area_px"]


def test_cancelled_run_without_close_leaves_complete_rows(tmp_path):
    log = RunLog(tmp_path)
    try:
        for frame in (1, 2, 3):
            log.add_frame(frame_row(frame), [selection_row(frame, "Sphere", True),
                                             selection_row(frame, "Glass", False)])
        frames = run_files.read_frames(tmp_path)
        selection = run_files.read_selection(tmp_path)
        assert [row["frame"] for row in frames] == [1, 2, 3]
        assert len(selection) == 6
        assert frames[2]["total_ms"] == 100.0 and frames[2]["rays"] == 120000
        assert not (tmp_path / "summary.json").exists()
    finally:
        log.__exit__(None, None, None)


def test_reader_ignores_a_half_written_last_line(tmp_path):
    with RunLog(tmp_path) as log:
        log.add_frame(frame_row(1), [selection_row(1, "Sphere", True)])
        log.add_frame(frame_row(2), [selection_row(2, "Sphere", True)])
    with open(tmp_path / "frames.csv", "a") as handle:
        handle.write("3,HYBRID,10")
    with open(tmp_path / "selection.csv", "a") as handle:
        handle.write("3,Sphere,1,0.1,0.8,3,0.02,1,0.02,1,0,0.02,1,\n")
    assert [row["frame"] for row in run_files.read_frames(tmp_path)] == [1, 2]
    assert [row["frame"] for row in run_files.read_selection(tmp_path)] == [1, 2]


def test_nan_and_inf_never_reach_the_logs(tmp_path):
    log = RunLog(tmp_path)
    log.add_frame(frame_row(1, total_ms=float("nan"), trace_ms=float("inf")),
                  [selection_row(1, "Sphere", True, A=np.float32("-inf"))])
    log.add_frame(frame_row(2, total_ms=50.0), [selection_row(2, "Sphere", True)])
    summary = log.close(CALLER_SUMMARY)
    for name in ("frames.csv", "selection.csv", "summary.json"):
        text = (tmp_path / name).read_text().lower()
        assert "nan" not in text and "inf" not in text, name
    frames = run_files.read_frames(tmp_path)
    assert frames[0]["total_ms"] is None and frames[0]["trace_ms"] is None
    assert run_files.read_selection(tmp_path)[0]["A"] is None
    assert summary["non_finite_values_dropped"] == 3
    assert summary["total_ms"]["mean"] == 50.0

    def refuse(constant):
        raise AssertionError(f"{constant} in summary.json")
    json.loads((tmp_path / "summary.json").read_text(), parse_constant=refuse)


def test_floats_are_written_with_six_significant_digits(tmp_path):
    with RunLog(tmp_path) as log:
        log.add_frame(frame_row(1, total_ms=1.0 / 3.0, raster_ms=123456789.125,
                                select_ms=np.float32(0.1), trace_ms=-0.0), [])
    row = dict(zip(header(tmp_path / "frames.csv"),
                   (tmp_path / "frames.csv").read_text().splitlines()[1].split(",")))
    assert row["total_ms"] == "0.333333"
    assert row["raster_ms"] == "1.23457e+08"
    assert row["select_ms"] == "0.1"
    assert row["trace_ms"] == "0"
    assert row["rays"] == "120000"


def test_bools_are_written_as_1_and_0_and_read_back_as_bools(tmp_path):
    with RunLog(tmp_path) as log:
        log.add_frame(frame_row(1), [selection_row(1, "007", np.bool_(True)),
                                     selection_row(1, "Glass", False, visible=False,
                                                   reason="not_visible")])
    lines = (tmp_path / "selection.csv").read_text().splitlines()
    assert lines[1].startswith("1,007,1,") and lines[1].endswith(",1,")
    assert lines[2].endswith(",0,not_visible")
    rows = run_files.read_selection(tmp_path)
    assert rows[0]["element"] == "007" and rows[0]["selected"] is True
    assert rows[1]["visible"] is False and rows[1]["reason"] == "not_visible"
    assert rows[0]["reason"] == ""


def test_summary_has_statistics_versions_and_machine(tmp_path):
    totals = [10.0, 20.0, 30.0, 40.0, 100.0]
    log = RunLog(tmp_path)
    for frame, total in enumerate(totals, start=1):
        log.add_frame(frame_row(frame, total_ms=total, raster_ms=frame),
                      [selection_row(frame, "Sphere", frame % 2 == 1)])
    log.close(dict(CALLER_SUMMARY, images="exr"))
    summary = run_files.read_summary(tmp_path)
    assert summary["scene"] == "atrium" and summary["path"] == "path1"
    assert summary["mode"] == "HYBRID" and summary["resolution"] == [64, 48]
    assert summary["budget_ms"] == 150.0 and summary["frame_count"] == 5
    # Steady (frames 2-5), the first frame on its own, all frames beside.
    assert summary["total_ms"] == {"mean": 47.5, "p50": 35.0, "p95": 91.0, "max": 100.0}
    assert summary["first_frame_ms"] == 10.0 and summary["p95_over_budget"] == pytest.approx(91.0 / 150.0)
    assert summary["all_frames_total_ms"] == {"mean": 40.0, "p50": 30.0, "p95": 88.0, "max": 100.0}
    assert summary["stage_mean_ms"] == {"raster_ms": 3.0, "select_ms": 1.0, "trace_ms": 70.0,
                                        "composite_ms": 9.0}
    assert summary["selection_flips_per_element_per_100_frames"]["per_element"] == {"Sphere": 80.0}
    assert summary["blender_version"] == "5.0.1"
    assert summary["embreex_version"] == "4.4.0.post1"
    assert summary["machine"]["cores"] == os.cpu_count()
    assert summary["machine"]["cpu_model"]
    assert summary["images"] == "exr"


def test_close_needs_the_callers_keys(tmp_path):
    log = RunLog(tmp_path)
    log.add_frame(frame_row(1), [])
    with pytest.raises(ValueError, match="blender_version"):
        log.close({"scene": "s", "path": "p", "resolution": (4, 4), "embreex_version": "4"})


def test_flips_count_state_changes_between_consecutive_appearances():
    rows = [{"frame": f, "element": "a", "selected": s} for f, s in zip((4, 1, 3, 2), (1, 1, 1, 0))]
    rows += [{"frame": f, "element": "b", "selected": True} for f in (1, 2, 3, 4)]
    rows += [{"frame": 1, "element": "c", "selected": True},
             {"frame": 3, "element": "c", "selected": False}]
    # a: 1 0 1 1 -> 2 flips in a 4-frame run; c: 1 . 0 . -> 1 flip.
    assert run_summary.flips_per_element_per_100(rows) == {"a": 50.0, "b": 0.0, "c": 25.0}
    assert run_summary.flips_per_element_per_100([]) == {}


@pytest.mark.parametrize("selected, reason", [(False, ""), (True, "over_budget"),
                                              (False, "too_expensive")])
def test_reason_must_match_the_contract(tmp_path, selected, reason):
    with RunLog(tmp_path) as log, pytest.raises(ValueError, match="reason"):
        log.add_frame(frame_row(1), [selection_row(1, "Sphere", selected, reason=reason)])


def test_missing_or_unknown_columns_are_refused(tmp_path):
    with RunLog(tmp_path) as log:
        row = frame_row(1)
        del row["rays"]
        with pytest.raises(ValueError, match="rays"):
            log.add_frame(row, [selection_row(1, "Sphere", True)])
        assert run_files.read_frames(tmp_path) == []
        assert (tmp_path / "selection.csv").read_text().splitlines()[1:] == []
        log.add_frame(frame_row(1), [])
        with pytest.raises(ValueError, match="surprise"):
            log.add_frame(frame_row(2, surprise=1), [])


def test_opening_a_run_dir_replaces_its_old_logs(tmp_path):
    first = RunLog(tmp_path)
    first.add_frame(frame_row(1), [])
    first.add_frame(frame_row(2), [])
    first.close(CALLER_SUMMARY)
    with RunLog(tmp_path) as second:
        second.add_frame(frame_row(7), [])
        assert not (tmp_path / "summary.json").exists()
    assert [row["frame"] for row in run_files.read_frames(tmp_path)] == [7]


def test_frame_image_path_prefers_exr_and_pads_to_four_digits(tmp_path):
    (tmp_path / "frames").mkdir()
    (tmp_path / "frames" / "0012.png").write_bytes(b"")
    assert run_files.frame_image_path(tmp_path, 12).name == "0012.png"
    (tmp_path / "frames" / "0012.exr").write_bytes(b"")
    assert run_files.frame_image_path(tmp_path, 12).name == "0012.exr"
    assert run_files.frame_image_path(tmp_path, 13) is None


def test_format_value_cleans_every_non_finite_kind():
    for value in (float("nan"), float("inf"), -math.inf, np.float16("nan"), np.float64("inf")):
        assert run_log.format_value(value) == ""
    assert run_log.format_value(np.int64(3)) == "3"
    assert run_log.format_value(None) == ""


def test_output_dir_problem_refuses_a_folder_under_a_file_and_creates_nothing(tmp_path):
    from phrt.phrt_addon.runs.folder import output_dir_problem
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    assert output_dir_problem(tmp_path / "new" / "run") is None
    assert not (tmp_path / "new").exists()
    problem = output_dir_problem(blocker / "run")
    assert problem is not None and "is a file, not a folder" in problem


def test_max_flips_in_a_window_of_10_frames():
    """Issue 20's "no element flips more than twice in 10 frames": the most flips of one element
    among any 10 consecutive frames, others' flips not added to it; leaving the view is no flip."""
    def rows(name, states, start=1, visible=None):
        return [{"frame": start + i, "element": name, "selected": state,
                 **({} if visible is None else {"visible": visible[i]})} for i, state in enumerate(states)]
    steady = rows("steady", [True] * 30)
    # Flips into frames 2, 3 and 10 (all between frames 1..10: 3), then 25 alone.
    blinking = rows("blink", [False, True, False] + [False] * 6 + [True] * 15 + [False] * 6)
    assert run_summary.max_flips_in_window(steady + blinking) == 3
    # Flips into frames 2 and 11: frames 1..11 are 11 frames, not one window of 10.
    apart = rows("apart", [False, True] + [True] * 8 + [False] * 5)
    assert run_summary.max_flips_in_window(apart) == 1
    assert run_summary.max_flips_in_window(rows("every", [i % 2 == 0 for i in range(40)])) == 9
    # Selected, out of view (so not selected), back and selected: no flip anyone saw.
    assert run_summary.max_flips_in_window(rows("away", [True, False, False, True],
                                                visible=[True, False, False, True])) == 0
    assert run_summary.max_flips_in_window([]) == 0
