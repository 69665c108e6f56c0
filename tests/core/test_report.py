"""The report of several runs: Table II, errors against the reference, plots, stability."""
import csv

import numpy as np
import pytest

from phrt.phrt_addon.report import metrics
from phrt.phrt_addon import report
from phrt.phrt_addon.runs.run_log import RunLog

HEIGHT, WIDTH = 48, 64
FRAMES = (1, 2, 3, 4)


def reference_frame(frame):
    """A smooth scene with a bright 'reflection' patch that moves with the frame."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    image = np.stack([x / WIDTH, y / HEIGHT, np.full_like(x, 0.3)], axis=-1) * 0.6
    image[10:30, 8 + 4 * frame:28 + 4 * frame] = (1.5, 1.2, 0.9)
    return image


def raster_frame(frame):
    """The reflection patch is missing: a large error."""
    image = reference_frame(frame)
    image[10:30, 8 + 4 * frame:28 + 4 * frame] = (0.05, 0.05, 0.1)
    return image


def hybrid_frame(frame):
    """The reflection is there but slightly noisy: a small error."""
    noise = np.random.default_rng(frame).normal(0.0, 0.02, (HEIGHT, WIDTH, 3))
    return np.clip(reference_frame(frame) + noise.astype(np.float32), 0.0, None)


def make_run(root, name, mode, total_ms, images="exr", frames=FRAMES, scene="atrium",
             path="path1", image_of=None, budget_ms=150.0, flicker=False):
    run_dir = root / name
    log = RunLog(run_dir)
    for frame in frames:
        selected = (frame % 2 == 0) if flicker else mode != "RASTER"
        log.add_frame(
            {"frame": frame, "mode": mode, "total_ms": total_ms + frame, "raster_ms": 15.0,
             "select_ms": 0.5, "trace_ms": total_ms - 20.0, "composite_ms": 4.5,
             "budget_ms": budget_ms, "predicted_trace_ms": total_ms - 25.0, "n_candidates": 2,
             "n_visible": 2, "n_selected": int(selected) + (mode == "RAYTRACE"),
             "rays": 1000 * frame},
            [{"frame": frame, "element": element, "visible": True, "A": 0.1, "P": 0.9, "D": 2.0,
              "V": 0.045, "Q": 1.0, "C": 0.045, "K": 1.0, "S": 0, "R": 0.045,
              "selected": state, "reason": "" if state else "over_budget"}
             for element, state in (("Mirror", selected), ("Glass", mode == "RAYTRACE"))])
        if images != "none":
            (run_dir / "frames").mkdir(exist_ok=True)
            metrics.write_image(run_dir / "frames" / f"{frame:04d}.{images}",
                                (image_of or reference_frame)(frame))
    log.close({"scene": scene, "path": path, "mode": mode, "resolution": (WIDTH, HEIGHT),
               "budget_ms": budget_ms, "blender_version": "5.0.1",
               "embreex_version": "4.4.0.post1", "images": images})
    return run_dir


@pytest.fixture(scope="module")
def three_modes(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    runs = [make_run(root, "atrium-path1-raster", "RASTER", 20.0, image_of=raster_frame),
            make_run(root, "atrium-path1-hybrid", "HYBRID", 100.0, image_of=hybrid_frame,
                     flicker=True),
            make_run(root, "atrium-path1-raytrace", "RAYTRACE", 400.0),
            make_run(root, "atrium-path1-hybrid-noimages", "HYBRID", 90.0, images="none")]
    files = report.build_report(runs, out_dir=root / "report")
    return root, runs, files


def section(markdown, title):
    """Lines of the markdown section ``## title``."""
    text = markdown.split(f"## {title}\n", 1)[1]
    return text.split("\n## ", 1)[0].splitlines()


def row_of(lines, start):
    return next(line for line in lines if line.startswith(start))


def read_errors(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_report_writes_every_file(three_modes):
    _, _, files = three_modes
    for path in (files.markdown, files.html, files.errors_csv):
        assert path.stat().st_size > 0
    for path in (files.error_vs_time_png, files.timeline_png):
        assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10000
    html = files.html.read_text()
    assert '<img src="error_vs_time.png"' in html and '<img src="timeline.png"' in html


def test_table_ii_has_mean_ms_per_mode_per_path_and_the_papers_ratios(three_modes):
    _, _, files = three_modes
    markdown = files.markdown.read_text()
    # total_ms = base + frame, frames 1-4: the steady mean (frames 2-4) = base + 3.  Ratios: ours 103 / 23
    # and 403 / 103; the paper's atrium path 1: 165.4 / 26.7 and 340.4 / 165.4.
    assert ("| atrium | path1 | 23.0 | 103.0 | 403.0 | 4.48 | 6.19 | 3.91 | 2.06 | atrium-path1-hybrid |"
            in markdown)


def test_errors_are_per_frame_against_the_raytrace_run(three_modes):
    _, _, files = three_modes
    rows = read_errors(files.errors_csv)
    assert {row["run"] for row in rows} == {"atrium-path1-raster", "atrium-path1-hybrid"}
    assert all(row["reference"] == "atrium-path1-raytrace" for row in rows)
    assert sorted(int(row["frame"]) for row in rows) == [1, 1, 2, 2, 3, 3, 4, 4]
    flip = {run: np.mean([float(r["flip"]) for r in rows if r["run"] == run])
            for run in ("atrium-path1-raster", "atrium-path1-hybrid")}
    assert flip["atrium-path1-raster"] > 0.1 > flip["atrium-path1-hybrid"] > 0.0
    raster = [row for row in rows if row["run"] == "atrium-path1-raster"]
    assert all(float(row["relmse"]) > 0.1 and float(row["psnr_db"]) < 30 for row in raster)


def test_error_table_averages_and_marks_the_reference(three_modes):
    root, _, files = three_modes
    rows = read_errors(files.errors_csv)
    mean_flip = np.mean([float(r["flip"]) for r in rows if r["run"] == "atrium-path1-raster"])
    lines = section(files.markdown.read_text(), "Error against the reference")
    assert f"| {mean_flip:.4f} |" in row_of(lines, "| atrium-path1-raster |")
    assert row_of(lines, "| atrium-path1-raytrace |").endswith("| 0.0000 | 0 | 100.00 | reference |")


def test_run_without_images_gets_timing_and_no_error(three_modes):
    _, _, files = three_modes
    lines = section(files.markdown.read_text(), "Error against the reference")
    line = row_of(lines, "| atrium-path1-hybrid-noimages |")
    assert "| – | – | – | no frame images (rendered with --images none): timing only |" in line
    assert "atrium-path1-hybrid-noimages" not in files.errors_csv.read_text()


def test_selection_stability_names_the_worst_element(three_modes):
    _, _, files = three_modes
    lines = section(files.markdown.read_text(), "Selection stability")
    # The flickering hybrid run selects Mirror on even frames: 3 flips in 4 frames.
    line = row_of(lines, "| atrium-path1-hybrid |")
    assert "| 2 | 37.50 | 75.00 | Mirror (75.00) |" in line


def test_pareto_front_of_three_points():
    # (30 ms, 0.3) is beaten by (20 ms, 0.2) on both time and error.
    assert report.pareto_front([10.0, 30.0, 20.0], [0.5, 0.3, 0.2]) == [0, 2]
    assert report.pareto_front([10.0, 20.0, 30.0], [0.5, 0.2, 0.0]) == [0, 1, 2]
    assert report.pareto_front([10.0, 10.0, 10.0], [0.4, 0.2, 0.2]) == [1, 2]


def test_averaged_psnr_is_that_of_the_mean_mse():
    # One frame identical to the reference (capped at 100 dB), one at 20 dB (MSE 0.01):
    # mean MSE 0.005 -> 23.01 dB, not the 60 dB of averaging decibels.
    errors = report.RunErrors(run=None, per_frame=[
        {"frame": 1, "flip": 0.0, "relmse": 0.0, "psnr_db": 100.0},
        {"frame": 2, "flip": 0.2, "relmse": 0.4, "psnr_db": 20.0}])
    assert errors.mean("psnr_db") == pytest.approx(23.0103, abs=1e-3)
    assert errors.mean("flip") == pytest.approx(0.1) and errors.mean("relmse") == pytest.approx(0.2)


def test_no_raytrace_run_and_no_reference_is_a_clear_error(tmp_path):
    run = make_run(tmp_path, "hybrid", "HYBRID", 100.0, images="none")
    with pytest.raises(ValueError, match="no reference run.*--reference"):
        report.build_report([run], out_dir=tmp_path / "report")


def test_explicit_reference_and_frames_matched_by_number(tmp_path):
    hybrid = make_run(tmp_path, "hybrid", "HYBRID", 100.0, frames=(1, 2, 3, 4))
    raster = make_run(tmp_path, "raster", "RASTER", 20.0, frames=(3, 4, 5),
                      image_of=raster_frame, images="png")
    files = report.build_report([raster], reference=hybrid, out_dir=tmp_path / "report")
    rows = read_errors(files.errors_csv)
    assert [(row["run"], row["reference"], row["frame"]) for row in rows] == [
        ("raster", "hybrid", "3"), ("raster", "hybrid", "4")]
    assert "2 of 3 frames compared" in files.markdown.read_text()


def test_errors_only_against_the_reference_of_the_same_path(tmp_path):
    runs = [make_run(tmp_path, "p1-raytrace", "RAYTRACE", 400.0),
            make_run(tmp_path, "p1-hybrid", "HYBRID", 100.0, image_of=hybrid_frame),
            make_run(tmp_path, "p2-hybrid", "HYBRID", 100.0, path="path2")]
    files = report.build_report(runs, out_dir=tmp_path / "report")
    assert {row["run"] for row in read_errors(files.errors_csv)} == {"p1-hybrid"}
    markdown = files.markdown.read_text()
    assert "| atrium | path2 | – | 103.0 | – |" in markdown
    line = row_of(section(markdown, "Error against the reference"), "| p2-hybrid |")
    assert line.endswith("| – | – | – | no reference run for this path: error not measured |")


def test_damaged_frame_image_is_noted_not_fatal(tmp_path):
    reference = make_run(tmp_path, "raytrace", "RAYTRACE", 400.0)
    hybrid = make_run(tmp_path, "hybrid", "HYBRID", 100.0, image_of=hybrid_frame)
    (hybrid / "frames" / "0002.exr").write_bytes(b"damaged")
    files = report.build_report([hybrid, reference], out_dir=tmp_path / "report")
    line = row_of(section(files.markdown.read_text(), "Error against the reference"), "| hybrid |")
    assert "not compared:" in line and "0002.exr" in line
    assert read_errors(files.errors_csv) == []


def test_unfinished_run_dir_is_refused(tmp_path):
    with RunLog(tmp_path / "cancelled") as log:
        log.add_frame({"frame": 1, "mode": "HYBRID", "total_ms": 1.0, "raster_ms": 1.0,
                       "select_ms": 0.0, "trace_ms": 0.0, "composite_ms": 0.0,
                       "budget_ms": 1.0, "predicted_trace_ms": 0.0, "n_candidates": 0,
                       "n_visible": 0, "n_selected": 0, "rays": 0}, [])
    with pytest.raises(ValueError, match="did not finish"):
        report.build_report([tmp_path / "cancelled"], out_dir=tmp_path / "report")
    with pytest.raises(ValueError, match="not a directory"):
        report.build_report([tmp_path / "missing"], out_dir=tmp_path / "report")
