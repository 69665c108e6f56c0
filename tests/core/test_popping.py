"""Popping (phrt_addon/report/popping.py) on runs written by hand: multilayer EXRs with the Combined
and PHRT Element passes named as Blender 5.0 names them, and real RunLog logs.  No bpy."""
import numpy as np
import OpenEXR
import pytest

from phrt.phrt_addon.report import metrics, popping
from phrt.phrt_addon.runs import run_files
from phrt.phrt_addon.runs.run_log import RunLog

HEIGHT, WIDTH = 40, 60
# Element 0 ("Ball") covers a square on the left, element 1 ("Box") one on the right.
BALL = (slice(10, 26), slice(6, 22))
BOX = (slice(12, 28), slice(36, 52))


def write_frame(path, image, element):
    channels = {f"ViewLayer.Combined.{c}": np.ascontiguousarray(image[..., i], dtype=np.float32)
                for i, c in enumerate("RGB")}
    channels["ViewLayer.PHRT Element.X"] = np.ascontiguousarray(element, dtype=np.float32)
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    OpenEXR.File(header, channels).write(str(path))


def scene_image(frame, ball_traced, box_traced):
    """A background drifting with the camera; the ball is bright when traced and dark when
    raster (a reflection that pops); the box looks the same either way."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    image = np.stack([(x + frame) / WIDTH, y / HEIGHT, np.full_like(x, 0.2)], axis=-1) * 0.5
    image[BALL] = (0.9, 0.8, 0.2) if ball_traced else (0.05, 0.05, 0.08)
    image[BOX] = (0.3, 0.5, 0.7)
    return image


def element_image():
    element = np.zeros((HEIGHT, WIDTH), np.float32)
    element[BALL] = 1  # index 0 + 1
    element[BOX] = 2
    return element


def make_run(root, name, states):
    """states: per frame (ball selected, box selected)."""
    run_dir = root / name
    log = RunLog(run_dir)
    (run_dir / "frames").mkdir()
    for frame, (ball, box) in enumerate(states, start=1):
        log.add_frame({"frame": frame, "mode": "HYBRID", "total_ms": 10.0, "raster_ms": 5.0, "select_ms": 0.1,
                       "trace_ms": 4.0, "composite_ms": 0.9, "budget_ms": 10.0, "predicted_trace_ms": 4.0,
                       "n_candidates": 2, "n_visible": 2, "n_selected": int(ball) + int(box), "rays": 0},
                      [{"frame": frame, "element": element, "visible": True, "A": 0.1, "P": 0.5, "D": 2.0,
                        "V": 1.0, "Q": 1.0, "C": 1.0, "K": 1.0, "S": 0, "R": 1.0, "selected": chosen,
                        "reason": "" if chosen else "over_budget"}
                       for element, chosen in (("Ball", ball), ("Box", box))])
        write_frame(run_dir / "frames" / f"{frame:04d}.exr", scene_image(frame, ball, box), element_image())
    log.close({"scene": "test", "path": "path1", "resolution": [WIDTH, HEIGHT], "blender_version": "5.0.1",
               "embreex_version": "4.4.0.post1"})
    return run_dir


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("popping")
    reference = make_run(root, "raytrace", [(True, True)] * 4)
    # The ball switches off at frame 3 (a pop); the box switches at frames 2 and 4 (invisible).
    hybrid = make_run(root, "hybrid", [(True, False), (True, True), (False, True), (False, False)])
    return reference, hybrid


def test_element_pass_is_read_back_by_name(runs):
    _, hybrid = runs
    element = metrics.read_pass(hybrid / "frames" / "0001.exr", popping.ELEMENT_PASS)
    assert element.shape == (HEIGHT, WIDTH, 1)
    np.testing.assert_array_equal(element[..., 0], element_image())
    with pytest.raises(ValueError, match="no pass"):
        metrics.read_pass(hybrid / "frames" / "0001.exr", "PHRT Missing")


def test_a_visible_switch_pops_and_an_invisible_one_does_not(runs):
    reference, hybrid = runs
    result = popping.measure_popping(hybrid, reference)
    assert result.measured and result.frame_count == 4
    assert [(pop.frame, pop.element) for pop in result.pops] == [(2, "Box"), (3, "Ball"), (4, "Box")]
    ball = next(pop for pop in result.pops if pop.element == "Ball")
    assert ball.pixels == 16 * 16 and not ball.selected
    assert ball.run_flip > 0.3 and ball.popping > 0.3  # dark <-> bright inside the ball
    for pop in result.pops:
        if pop.element == "Box":
            assert abs(pop.popping) < 0.02  # same look traced or not: only the (equal) motion
    per_element = result.per_element()
    assert per_element["Box"][0] == 2 and per_element["Ball"][0] == 1
    assert result.per_100_frames() == pytest.approx(100.0 * sum(p.popping for p in result.pops) / 4)
    assert result.flips_per_100_frames() == pytest.approx(75.0)


def test_the_reference_itself_never_pops(runs):
    reference, _ = runs
    result = popping.measure_popping(reference, reference)
    assert result.pops == [] and result.per_100_frames() == 0.0


def test_runs_without_the_element_pass_are_noted(tmp_path):
    run_dir = tmp_path / "old"
    log = RunLog(run_dir)
    (run_dir / "frames").mkdir()
    log.add_frame({"frame": 1, "mode": "HYBRID", "total_ms": 1.0, "raster_ms": 1.0, "select_ms": 0.0,
                   "trace_ms": 0.0, "composite_ms": 0.0, "budget_ms": 1.0, "predicted_trace_ms": 0.0,
                   "n_candidates": 0, "n_visible": 0, "n_selected": 0, "rays": 0}, [])
    metrics.write_image(run_dir / "frames" / "0001.exr", np.zeros((4, 4, 3), np.float32))
    log.close({"scene": "test", "path": "path1", "resolution": [4, 4], "blender_version": "5.0.1",
               "embreex_version": "4.4.0.post1"})
    result = popping.measure_popping(run_dir, run_dir)
    assert not result.measured and "PHRT Element" in result.note and result.per_100_frames() is None


def test_a_change_of_rate_or_effects_while_traced_is_an_items_pop(tmp_path):
    """Under BENEFIT an element traced in both frames pops when its traced effects or its rate
    change: counted with kind "items", in the total and on its own."""
    reference = make_run(tmp_path, "raytrace", [(True, True)] * 4)
    hybrid = make_run(tmp_path, "benefit", [(True, True)] * 4)
    rows = []
    for frame, (ball_rate, box_effects) in enumerate([(1.0, "reflections"), (0.25, "reflections"),
                                                      (0.25, "reflections;shadows"), (0.25, "reflections;shadows")],
                                                     start=1):
        rows.append({"frame": frame, "element": "Ball", "selected": True, "effects": "reflections", "rate": ball_rate})
        rows.append({"frame": frame, "element": "Box", "selected": True, "effects": box_effects, "rate": 1.0})
    result = popping.measure_popping(hybrid, reference, selection_rows=rows)
    assert [(pop.frame, pop.element, pop.kind) for pop in result.pops] == [(2, "Ball", "items"), (3, "Box", "items")]
    assert result.per_100_frames("state") == 0.0
    assert result.per_100_frames("items") == pytest.approx(result.per_100_frames())


def test_the_reports_compact_selection_keeps_what_was_traced_so_items_pops_are_counted(tmp_path):
    """The report streams selection.csv into run_files.SelectionStates and hands that to popping:
    the effects and rate columns must survive it, or no "items" pop is ever measured (they were
    dropped before: every sweep's item_popping read 0)."""
    reference = make_run(tmp_path, "raytrace", [(True, True)] * 3)
    run_dir = tmp_path / "benefit"
    log = RunLog(run_dir)
    (run_dir / "frames").mkdir()
    for frame, effects in enumerate(["reflections", "reflections;shadows", "reflections;shadows"], start=1):
        log.add_frame({"frame": frame, "mode": "HYBRID", "total_ms": 10.0, "raster_ms": 5.0, "select_ms": 0.1,
                       "trace_ms": 4.0, "composite_ms": 0.9, "budget_ms": 10.0, "predicted_trace_ms": 4.0,
                       "n_candidates": 2, "n_visible": 2, "n_selected": 2, "rays": 0},
                      [{"frame": frame, "element": element, "visible": True, "A": 0.1, "P": 0.5, "D": 2.0,
                        "V": 1.0, "Q": 1.0, "C": 1.0, "K": 1.0, "S": 1, "R": 1.0, "selected": True, "reason": "",
                        "predicted_ms": 1.0, "benefit": 1.0, "effects": effects if element == "Ball" else "shadows",
                        "rate": 1.0} for element in ("Ball", "Box")])
        # The ball's look changes with its traced effects (its shadow term now traced).
        image = scene_image(frame, True, True)
        if frame >= 2:
            image[BALL] = (0.2, 0.6, 0.9)
        write_frame(run_dir / "frames" / f"{frame:04d}.exr", image, element_image())
    log.close({"scene": "test", "path": "path1", "resolution": [WIDTH, HEIGHT], "blender_version": "5.0.1",
               "embreex_version": "4.4.0.post1"})
    states = run_files.SelectionStates(run_dir)
    assert {(row["element"], row["effects"]) for row in states if row["frame"] == 2} == \
        {("Ball", "reflections;shadows"), ("Box", "shadows")}
    result = popping.measure_popping(run_dir, reference, selection_rows=states)
    assert [(pop.frame, pop.element, pop.kind) for pop in result.pops] == [(2, "Ball", "items")]
    assert result.per_100_frames("items") > 0.0
