"""summary.json as a run's commit record (run_log.RunLog with facts, run_files readers): it exists
from the start, is rewritten as frames complete at most once a second (or once a frame when
frames are slower), and the readers read only what it commits: the first frame_count rows, their
selection rows, and their images in the format it names.  The CSV reader keeps newlines and any
Unicode inside cells."""
import json

import pytest

from phrt.phrt_addon import report, schema
from phrt.phrt_addon.runs import run_files
from phrt.phrt_addon.runs.run_log import RunLog
from phrt.phrt_addon.runs import summary as run_summary

FACTS = {"scene": "atrium", "path": "path1", "resolution": [64, 48], "blender_version": "5.0.1",
         "embreex_version": "4.4.0.post1", "images": "none", "frames_planned": 10}


def frame_row(frame, mode="HYBRID"):
    return {"frame": frame, "mode": mode, "total_ms": 100.0 + frame, "raster_ms": 20.0, "select_ms": 1.0,
            "trace_ms": 70.0, "composite_ms": 9.0, "budget_ms": 150.0, "predicted_trace_ms": 65.0,
            "n_candidates": 1, "n_visible": 1, "n_selected": 1, "rays": 10}


def selection_row(frame, element, selected=True):
    return {"frame": frame, "element": element, "visible": True, "A": 0.1, "P": 0.8, "D": 3.0, "V": 0.02,
            "Q": 1.0, "C": 0.02, "K": 1.0, "S": 0, "R": 0.02, "selected": selected,
            "reason": "" if selected else "over_budget"}


class Clock:
    """A clock the test moves by hand: the summary's rewrites are counted, not timed."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def test_the_summary_exists_from_the_start_and_says_partial(tmp_path):
    RunLog(tmp_path / "run", facts=FACTS)
    summary = run_files.read_summary(tmp_path / "run")
    assert summary["partial"] is True and summary["frame_count"] == 0 and summary["scene"] == "atrium"


def test_the_summary_is_rewritten_at_most_once_a_second_or_once_a_frame(tmp_path):
    clock = Clock()
    log = RunLog(tmp_path / "run", facts=FACTS, clock=clock)
    assert log.summaries_written == 1
    for frame in range(1, 11):  # ten fast frames (0.25 s each): a rewrite every fourth frame
        clock.now += 0.25
        log.add_frame(frame_row(frame), [selection_row(frame, "Glass")])
    assert log.summaries_written == 1 + 2
    assert run_files.read_summary(tmp_path / "run")["frame_count"] == 8
    for frame in range(11, 14):  # slow frames (2 s each): every frame
        clock.now += 2.0
        log.add_frame(frame_row(frame), [])
    assert log.summaries_written == 1 + 2 + 3
    assert log.close({})["partial"] is False


def test_a_killed_run_reads_back_only_what_its_summary_commits(tmp_path):
    """Frames logged after the last summary (a kill before the next rewrite) are not read."""
    clock = Clock()
    folder = tmp_path / "run"
    log = RunLog(folder, facts={**FACTS, "images": "png"}, clock=clock)
    (folder / "frames").mkdir()
    for frame in (1, 2, 3):
        (folder / "frames" / f"{frame:04d}.png").write_bytes(b"png")
        clock.now += 1.0 if frame < 3 else 0.1  # frame 3 is logged but the summary is not rewritten
        log.add_frame(frame_row(frame), [selection_row(frame, "Glass")])
    # never closed: the process was killed here
    summary = run_files.read_summary(folder)
    assert summary["partial"] is True and summary["frame_count"] == 2
    assert [row["frame"] for row in run_files.read_frames(folder)] == [1, 2]
    assert [row["frame"] for row in run_files.read_selection(folder)] == [1, 2]
    assert sorted(run_files.run_images(folder)) == [1, 2]
    assert (folder / schema.FRAMES_CSV).read_text().count("\n") == 1 + 3  # the row is there, not committed


def test_images_the_summary_does_not_name_are_never_read(tmp_path):
    """An EXR left by an earlier run stays unseen when this run writes no images."""
    folder = tmp_path / "run"
    (folder / "frames").mkdir(parents=True)
    (folder / "frames" / "0001.exr").write_bytes(b"old")
    log = RunLog(folder, facts=FACTS)
    log.add_frame(frame_row(1, mode="RAYTRACE"), [])
    log.close({})
    assert run_files.frame_image_path(folder, 1) is None and run_files.run_images(folder) == {}
    loaded = report.runs.load_run(folder)
    assert not loaded.has_images


@pytest.mark.parametrize("name", ["Wall\u2028Glass", "Wall\x85Glass", "Wall\fGlass", "two\nlines", 'quote"d,comma'])
def test_element_names_with_line_breaks_and_any_unicode_survive(tmp_path, name):
    log = RunLog(tmp_path / "run", facts=FACTS)
    log.add_frame(frame_row(1), [selection_row(1, name), selection_row(1, "plain", False)])
    log.add_frame(frame_row(2), [selection_row(2, name, False)])
    log.close({})
    rows = run_files.read_selection(tmp_path / "run")
    assert [(row["frame"], row["element"]) for row in rows] == [(1, name), (1, "plain"), (2, name)]
    states = run_files.SelectionStates(tmp_path / "run")
    assert states.flips_per_element_per_100() == run_summary.flips_per_element_per_100(rows) == {name: 50.0,
                                                                                             "plain": 0.0}


def test_a_record_cut_inside_a_quoted_cell_is_not_read(tmp_path):
    (tmp_path / schema.FRAMES_CSV).write_text('frame,mode\n1,"a\nb"\n2,"cut\n', encoding="utf-8")
    assert [row["frame"] for row in run_files.read_frames(tmp_path)] == [1]
    (tmp_path / schema.FRAMES_CSV).write_text('frame,mode\n1,a\n2,b', encoding="utf-8")
    assert [row["frame"] for row in run_files.read_frames(tmp_path)] == [1]


def test_a_partial_run_is_reported_as_partial(tmp_path):
    reference = RunLog(tmp_path / "reference", facts={**FACTS, "frames_planned": 2})
    for frame in (1, 2):
        reference.add_frame(frame_row(frame, "RAYTRACE"), [])
    reference.close({})
    clock = Clock()
    killed = RunLog(tmp_path / "killed", facts=FACTS, clock=clock)
    clock.now = 5.0
    killed.add_frame(frame_row(1), [selection_row(1, "Glass")])
    files = report.build_report([tmp_path / "reference", tmp_path / "killed"], out_dir=tmp_path / "report")
    text = files.markdown.read_text()
    assert "Partial runs" in text and "killed (1 of 10 frames)" in text
    assert not [path.name for path in (tmp_path / "report").iterdir() if ".tmp-" in path.name]
    json.loads((tmp_path / "report" / "sweep.json").read_text())
