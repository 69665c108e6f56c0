"""The report of a sweep (phrt_addon/report.py): sweep.csv, sweep.json and the markdown agree;
the regret read from an oracle folder; the curves' axes; Table II beside the paper's.  Runs,
images and the oracle folder are written by hand (real RunLog, EXR and oracle files).  No bpy."""
import csv
import json

import numpy as np
import pytest

from phrt.phrt_addon.report import metrics, oracle
from phrt.phrt_addon import report
from phrt.phrt_addon.runs.run_log import RunLog

HEIGHT, WIDTH = 32, 48
FRAMES = (1, 2, 3, 4)


def reference_frame(frame):
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32)
    image = np.stack([x / WIDTH, y / HEIGHT, np.full_like(x, 0.3)], axis=-1) * 0.6
    image[8:20, 4 + 2 * frame:20 + 2 * frame] = (1.4, 1.1, 0.8)
    return image


def degraded(amount):
    """A frame whose reflection patch is ``amount`` of the way to missing."""
    def frame_of(frame):
        image = reference_frame(frame)
        patch = image[8:20, 4 + 2 * frame:20 + 2 * frame]
        image[8:20, 4 + 2 * frame:20 + 2 * frame] = (1 - amount) * patch + amount * 0.05
        return image
    return frame_of


def make_run(root, name, mode, total_ms, amount, budget_at=None, budget_ms=150.0, **summary):
    run_dir = root / name
    log = RunLog(run_dir)
    (run_dir / "frames").mkdir(parents=True)
    for frame in FRAMES:
        selected = mode == "RAYTRACE" or (mode == "HYBRID" and amount < 0.5)
        log.add_frame({"frame": frame, "mode": mode, "total_ms": total_ms + frame, "raster_ms": 20.0,
                       "select_ms": 0.5, "trace_ms": 1.0, "composite_ms": 1.0, "budget_ms": budget_ms,
                       "predicted_trace_ms": 1.0, "n_candidates": 1, "n_visible": 1,
                       "n_selected": int(selected), "rays": 10, "time_left_ms": 5.0,
                       # the G-buffer 1.25x slower in the hybrid runs than in the raster run: the machine's drift
                       "gbuffer_ms": (1.25 if mode == "HYBRID" else 1.0) * (10.0 + frame)},
                      [{"frame": frame, "element": "Mirror", "visible": True, "A": 0.1, "P": 0.9, "D": 2.0,
                        "V": 1.0, "Q": 1.0, "C": 1.0, "K": 1.0, "S": 0, "R": 1.0, "selected": selected,
                        "reason": "" if selected else "over_budget"}])
        metrics.write_image(run_dir / "frames" / f"{frame:04d}.exr", degraded(amount)(frame))
    log.close({"scene": "arcade", "path": "path1", "resolution": [WIDTH, HEIGHT], "blender_version": "5.0.1",
               "embreex_version": "4.4.0.post1", "budget_at": budget_at, **summary})
    return run_dir


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    root = tmp_path_factory.mktemp("sweep")
    runs = [make_run(root, "arcade-path1-raster", "RASTER", 20.0, 1.0),
            make_run(root, "arcade-path1-raytrace", "RAYTRACE", 100.0, 0.0)]
    for fraction, total, amount in ((0.25, 40.0, 0.6), (0.75, 80.0, 0.2)):
        budget = 20.0 + fraction * 80.0
        runs.append(make_run(root, f"arcade-path1-hybrid-at{fraction:.2f}-measured", "HYBRID", total, amount,
                             budget_at=fraction, budget_ms=budget, cost_mode="measured", selection_weight=0.5,
                             selection_order="relevance", relevance="paper"))
        runs.append(make_run(root, f"arcade-path1-hybrid-at{fraction:.2f}-error", "HYBRID", total + 1, amount / 2,
                             budget_at=fraction, budget_ms=budget, cost_mode="measured", selection_weight=0.5,
                             selection_order="relevance", relevance="error"))
    # An oracle folder for three of the four hybrid runs (the last is 'not in the oracle').
    candidates = oracle.FrameCandidates(frame=4, names=["Mirror"], cost_ms=np.array([3.0]),
                                        benefit=np.array([0.05]), flip_raster=0.06)
    rows = [oracle.regret_row(run.name, 4, 40.0, 35.0, 5.0, set(), 0.03 + index * 0.01, {"Mirror"}, 0.01,
                              candidates)
            for index, run in enumerate(runs[2:5])]
    oracle.write_results(root / "oracle", 4, [4], [candidates], rows, {run.name: run for run in runs[2:5]})
    files = report.build_report(runs, out_dir=root / "report")
    return root, runs, files


def read_csv(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def markdown_table(markdown, title):
    lines = markdown.split(f"## {title}\n", 1)[1].split("\n## ", 1)[0].splitlines()
    rows = [line for line in lines if line.startswith("| ")]
    header = [cell.strip() for cell in rows[0].strip("|").split(" | ")]
    return [dict(zip(header, (cell.strip() for cell in row.strip("|").split(" | ")))) for row in rows[1:]]


def test_sweep_csv_has_the_contract_columns_and_one_row_per_run(sweep):
    _, runs, files = sweep
    rows = read_csv(files.sweep_csv)
    assert list(rows[0])[:12] == ["run", "mode", "cost_mode", "budget_ms", "mean_ms", "p95_ms", "flip", "relmse",
                                  "psnr", "regret", "flips_per_100", "popping"]
    assert [row["run"] for row in rows] == [run.name for run in runs]
    hybrid = next(row for row in rows if row["run"] == "arcade-path1-hybrid-at0.25-measured")
    assert float(hybrid["budget_ms"]) == 40.0 and float(hybrid["budget_at"]) == 0.25
    # Steady: frames 2-4 of total_ms = 40 + frame; the first frame (41) on its own.
    assert float(hybrid["mean_ms"]) == pytest.approx(43.0) and float(hybrid["first_frame_ms"]) == pytest.approx(41.0)
    assert float(hybrid["p95_over_budget"]) == pytest.approx(43.9 / 40.0)
    assert float(hybrid["regret"]) == pytest.approx(0.02)
    # The oracle gains 0.06 - 0.01 over raster; the heuristic got 0.03 of it and lost 0.02.
    assert float(hybrid["captured"]) == pytest.approx(0.6) and float(hybrid["regret_share"]) == pytest.approx(0.4)
    assert int(hybrid["judged_frames"]) == 1 and hybrid["captured_lo"] == ""  # one frame: no interval
    assert hybrid["variant_name"] == "measured"
    # The machine's drift against the raster run the budgets came from, and T against the oracle's capacity.
    assert float(hybrid["speed_vs_raster"]) == pytest.approx(1.25)
    assert float(hybrid["time_left_share"]) == pytest.approx(1.0)  # T 5 ms against 40 - 35
    raster = next(row for row in rows if row["mode"] == "RASTER")
    assert raster["speed_vs_raster"] == "" and raster["time_left_share"] == ""
    # The oracle's 0.01 against the raster frame's 0.06: it removes 5/6 of the frame's error.
    assert float(hybrid["oracle_reduction"]) == pytest.approx(5.0 / 6.0) and raster["oracle_reduction"] == ""
    assert hybrid["lockstep_runs"] == ""  # one run after the other
    assert raster["budget_ms"] == "" and raster["regret"] == "" and float(raster["flip"]) > float(hybrid["flip"])


def test_sweep_csv_json_and_markdown_agree(sweep):
    _, _, files = sweep
    rows = read_csv(files.sweep_csv)
    document = json.loads(files.sweep_json.read_text())
    assert document["columns"] == list(report.SWEEP_COLUMNS)
    table = markdown_table(files.markdown.read_text(), report.SWEEP_TABLE_TITLE)
    assert len(rows) == len(document["runs"]) == len(table)
    for csv_row, json_row, md_row in zip(rows, document["runs"], table):
        for key, title, spec in report.SWEEP_TABLE_FORMATS:
            text, value = csv_row[key], json_row[key]
            if text == "":
                assert value is None and md_row[title] == "–", key
                continue
            if spec is None:
                assert str(value) == text == md_row[title], key
                continue
            assert float(text) == pytest.approx(float(value), rel=1e-5), key
            # The markdown shows the same number at its own precision.
            shown = float(md_row[title])
            decimals = int(spec[1:-1]) if spec.endswith("f") else None
            if decimals is not None:
                assert abs(shown - float(text)) <= 0.5 * 10 ** -decimals + 1e-9, (key, shown, text)
            else:
                assert shown == pytest.approx(float(text), rel=1e-3), key


def test_regret_comes_from_the_oracle_and_missing_runs_are_noted(sweep):
    _, _, files = sweep
    table = markdown_table(files.markdown.read_text(), "Regret against the oracle")
    by_run = {row["Run"]: row for row in table}
    assert by_run["arcade-path1-hybrid-at0.25-measured"]["Mean regret"] == "0.0200"
    assert by_run["arcade-path1-hybrid-at0.25-measured"]["Oracle chose, heuristic did not (frames)"] == "Mirror (1)"
    assert by_run["arcade-path1-hybrid-at0.75-error"]["Note"] == "not in the oracle"
    assert (files.markdown.parent / "regret.csv").is_file()
    assert "outside every timed region" in files.markdown.read_text()


def test_relevance_comparison_names_the_winner(sweep):
    _, _, files = sweep
    markdown = files.markdown.read_text()
    assert "## Paper relevance against error-aware relevance: arcade / path1" in markdown
    # Half the error, but one judged frame per run gives no interval: no difference is declared.
    assert "no difference at any of the 2 budget(s)" in markdown and "wins" not in markdown
    assert "the error-aware R is lower at 2 and higher at 0 of them" in markdown


def test_table_ii_shows_the_paper_heuristic_beside_the_papers_sponza_ratios(sweep):
    _, _, files = sweep
    row = markdown_table(files.markdown.read_text(), "Render times (ms per frame), after the paper's Table II")[0]
    # The baseline at the budget nearest 0.4 (0.25): 43 ms steady; raster 23, raytrace 103.
    assert row["Hybrid run"] == "arcade-path1-hybrid-at0.25-measured"
    assert (row["Raster rendering"], row["Hybrid rendering"], row["Ray tracing rendering"]) == ("23.0", "43.0", "103.0")
    assert row["Hybrid / raster"] == "1.87" and row["Ray tracing / hybrid"] == "2.40"
    assert row["Paper: hybrid / raster"] == "6.72" and row["Paper: ray tracing / hybrid"] == "3.54"  # Sponza path 1


def test_every_plot_has_titles_and_labelled_axes_with_units(sweep):
    _, _, files = sweep
    assert set(files.figures) == {"error_vs_time.png", "timeline.png", "selection_quality.png"}
    for name, figure in files.figures.items():
        assert (files.markdown.parent / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        for axes in figure.axes:
            if not axes.get_visible():
                continue
            assert axes.get_ylabel(), name
            if name != "timeline.png":
                assert axes.get_title(), name
                assert "(ms)" in axes.get_xlabel(), name
    curves = files.figures["error_vs_time.png"].axes
    assert "LDR-FLIP" in curves[0].get_ylabel() and "relMSE" in curves[1].get_ylabel()
    legend = [text.get_text() for text in curves[0].get_legend().get_texts()]
    assert {"paper R, measured cost, I=0.5", "error-aware R, measured cost, I=0.5", "raster",
            "ray traced (reference)", "Pareto front"} <= set(legend)


def test_the_report_leads_with_the_curve_and_the_variants_per_budget(sweep):
    _, _, files = sweep
    markdown = files.markdown.read_text()
    assert markdown.index("error_vs_time.png") < markdown.index("## Results: arcade / path1") \
        < markdown.index("## Render times") < markdown.index("## Runs\n")
    rows = markdown_table(markdown, "Results: arcade / path1")
    measured = next(row for row in rows if row["Variant"] == "measured" and row["Budget at"] == "0.25")
    assert measured["Budget ms"] == "40" and measured["Captured [90%]"] == "0.60" and measured["Judged frames"] == "1"
    assert "measured against error: no difference" in markdown


def test_variants_differ_only_when_their_intervals_do_not_overlap():
    from phrt.phrt_addon.report import results
    row = {"mode": "HYBRID", "variant": "x", "captured_lo": 0.5, "captured_hi": 0.7, "captured": 0.6}
    overlapping = [{**row, "variant_name": "measured"},
                   {**row, "variant_name": "benefit", "captured": 0.66, "captured_lo": 0.61, "captured_hi": 0.8}]
    assert results.verdicts(overlapping) == ["measured against benefit: no difference"]
    apart = [overlapping[0], {**overlapping[1], "captured": 0.85, "captured_lo": 0.75, "captured_hi": 0.93}]
    assert results.verdicts(apart) == ["measured against benefit: benefit captures more"]


def test_the_verdict_gives_the_paired_difference_on_the_frames_both_runs_were_judged_on():
    from phrt.phrt_addon.report import results
    generator = np.random.default_rng(5)
    possible = generator.gamma(0.6, 0.004, 24)
    shared = generator.normal(0, 0.4, 24)  # both runs miss the same hard frames
    errors = {name: {frame: (0.02 + gain, 0.02 + gain * (1 - share - lift + noise), 0.02)
                     for frame, gain, lift, noise in zip(range(4, 100, 4), possible, shared,
                                                          generator.normal(0, 0.03, 24))}
              for name, share in (("measured", 0.4), ("benefit", 0.6))}
    rows = [{"mode": "HYBRID", "variant": "x", "variant_name": name, "captured": 0.5, "captured_lo": 0.1,
             "captured_hi": 0.9, "judged_errors": errors[name]} for name in ("measured", "benefit")]
    (sentence,) = results.verdicts(rows)
    assert sentence.startswith("measured against benefit: no difference; paired on the same 24 frames: -0.")
    assert sentence.endswith("benefit captures more")
    rows[1]["judged_errors"] = {}  # a run without an oracle: its own intervals only
    assert results.verdicts(rows) == ["measured against benefit: no difference"]
