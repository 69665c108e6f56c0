"""``make selection-eval``: the selections judged on the held-out paths (issue 20's measure).

For each judged path (arcade path3, atrium path2, atrium path3 and a path of the
showcase scene; never the paths constants are fitted on: arcade path1-2, atrium
path1) a ``phrt sweep`` at 320x240 over the given frames, budgets F = 0.1, 0.25,
0.5, 0.75, 0.9 of the way from raster to ray traced time, the oracle every 4th
frame, variants measured (the paper's), error, benefit and tiers (those the sweep knows).
Then one table, variant x budget x path: the captured share of the oracle's
error reduction with its 90% interval, pops per 100 frames, p95 / budget, the
share of frames within budget, printed and written to ``OUT/selection_eval.csv``
and ``OUT/selection_eval.md``, with how far the machine drifted between the raster run the
budgets came from and the hybrid runs (their G-buffer ms over the raster run's) and the share of
the oracle's time each run still had.  The hybrid runs of a path are rendered in lockstep
(``phrt sweep --lockstep``: frame by frame together, so that every budget and variant meets the
machine in the same state; ``--one-after-another`` for the plain sweep).  LONG (hours at 200+
frames per path); a sweep already complete is reused, so an interrupted evaluation resumes.

    python tools/selection_eval.py [--out out/selection-eval] [--frames 1-240]
        [--paths arcade/path3,atrium/path2,atrium/path3,showcase/orbit] [--budget-at 0.1,...]
        [--variants measured,error,benefit,tiers] [--oracle-every 4] [--resolution 320x240]
        [--one-after-another]

The showcase scene has no camera path of its own: this tool saves it with the
camera orbiting the objects over the frames (``showcase.blend`` in OUT, path
``orbit``).
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
from pathlib import Path

DEFAULT_PATHS = "arcade/path3,atrium/path2,atrium/path3,showcase/orbit"
DEFAULT_BUDGETS = "0.1,0.25,0.5,0.75,0.9"
DEFAULT_VARIANTS = "measured,error,benefit,tiers"
COLUMNS = ("path", "variant", "budget_at", "budget_ms", "captured", "captured_lo", "captured_hi", "judged_frames",
           "popping", "item_popping", "flips_per_100", "max_flips_10", "p95_over_budget", "raster_p95_over_budget", "within_budget", "flip", "mean_ms",
           "first_frame_ms", "speed_vs_raster", "time_left_share", "oracle_reduction")
ORBIT_RADIUS = 9.0
ORBIT_HEIGHT = 3.5


def save_orbiting_showcase(path: Path, frames: tuple[int, int]) -> Path:
    """The showcase scene with its camera (named ``orbit``) going once around the scene over ``frames``."""
    import bpy

    from phrt.sample_scenes.showcase import build_showcase
    scene = build_showcase(320, 240)
    camera = scene.camera
    camera.name = "orbit"
    target = bpy.data.objects.new("orbit-target", None)
    scene.collection.objects.link(target)
    constraint = camera.constraints.new("TRACK_TO")
    constraint.target = target
    start, end = frames
    scene.frame_start, scene.frame_end = start, end
    for frame in range(start, end + 1, max(1, (end - start) // 24)):
        angle = 2.0 * math.pi * (frame - start) / max(end - start, 1)
        camera.location = (ORBIT_RADIUS * math.cos(angle), ORBIT_RADIUS * math.sin(angle), ORBIT_HEIGHT)
        camera.keyframe_insert("location", frame=frame)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def _variants(requested):
    from phrt.phrt_addon.runs import plan
    known = [name for name in requested.split(",") if name in plan.VARIANTS]
    missing = [name for name in requested.split(",") if name not in plan.VARIANTS]
    if missing:
        print(f"selection-eval: variant(s) {', '.join(missing)} not in this checkout; evaluating "
              f"{', '.join(known)}", file=sys.stderr)
    return ",".join(known)


class EvaluationInterrupted(Exception):
    """A sweep was stopped by a signal (its exit status): the evaluation stops, no table is written."""

    def __init__(self, status: int):
        super().__init__(f"a sweep was interrupted (status {status})")
        self.status = status


def evaluate(args) -> list:
    from phrt import cli
    from phrt.cli import blender_process as blender
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    variants = _variants(args.variants)
    first, last = (int(part) for part in args.frames.split("-"))
    table = []
    for target in args.paths.split(","):
        scene, path = target.split("/")
        if scene == "showcase":
            blend = out / "showcase.blend"
            if not blend.exists():
                blender.blender()
                with blender.quiet_stdout():
                    save_orbiting_showcase(blend, (first, last))
            scene = str(blend.resolve())
        sweep_dir = out / target.replace("/", "-")
        if not args.table_only:
            status = cli.main(["sweep", scene, "--path", path, "--frames", args.frames, "--budget-at", args.budget_at,
                               "--variants", variants, "--oracle-every", str(args.oracle_every),
                               "--resolution", args.resolution, "--out", str(sweep_dir)]
                              + ([] if args.one_after_another else ["--lockstep"]))
            if status >= 128:  # a signal stopped it: so it stops the evaluation (rerun to resume)
                raise EvaluationInterrupted(status)
            if status != 0:
                print(f"selection-eval: the sweep of {target} failed (status {status})", file=sys.stderr)
        sweep_csv = sweep_dir / "report" / "sweep.csv"
        if not sweep_csv.is_file():
            continue
        with open(sweep_csv, newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
        # The raster run's own p95 against each budget: the floor no selection can go below (a
        # frame that traces nothing still costs a raster frame, noise included); from the raster run
        # rendered with the hybrid runs when there is one (lockstep: the machine they met).
        raster_p95 = _shared_raster_p95(sweep_dir)
        if raster_p95 is None:
            raster_p95 = next((float(row["p95_ms"]) for row in rows if row["mode"] == "RASTER" and row.get("p95_ms")),
                              None)
        for row in rows:
            if row["mode"] != "HYBRID":
                continue
            floor = (raster_p95 / float(row["budget_ms"])) if raster_p95 and row.get("budget_ms") else ""
            table.append({"path": target, "variant": row.get("variant_name") or row["variant"], "run": row["run"],
                          **{key: row.get(key, "") for key in COLUMNS[2:]}, "raster_p95_over_budget": floor,
                          "max_flips_10": _max_flips(sweep_dir / row["run"])})
    return table


def _shared_raster_p95(sweep_dir: Path):
    """The steady p95 frame ms of the raster run the sweep's oracle took its shared times from
    (``oracle.json`` ``shared_from``: in lockstep the group raster run), or None."""
    from phrt.phrt_addon.report import oracle
    from phrt.phrt_addon.runs import run_files, steady
    results = oracle.read_results(sweep_dir / oracle.ORACLE_DIR)
    name = results.info.get("shared_from") if results is not None else None
    if not name or not results.is_shared_from(sweep_dir / name):
        return None
    return steady.steady_stats(run_files.read_frames(sweep_dir / name))["p95"]


PAIRS = (("benefit", "measured"), ("tiers", "benefit"))
PAIRED_COLUMNS = ("path", "budget_at", "first", "second", "difference", "difference_lo", "difference_hi",
                  "judged_frames", "verdict")


def paired(table, out: Path) -> list:
    """Per path and budget, each of :data:`PAIRS` present: the captured share of the first variant
    less the second's on the same judged frames, with the paired block-bootstrap interval
    (``report.captured.paired_difference``); the verdict says a difference only when the interval
    leaves out 0."""
    from phrt.phrt_addon.report import captured
    from phrt.phrt_addon.report import oracle
    rows = []
    for path in dict.fromkeys(row["path"] for row in table):
        results = oracle.read_results(out / path.replace("/", "-") / oracle.ORACLE_DIR)
        if results is None:
            continue
        runs = {(row["variant"], row["budget_at"]): row["run"] for row in table if row["path"] == path}
        for budget in dict.fromkeys(budget for _, budget in runs):
            for first, second in PAIRS:
                if (first, budget) not in runs or (second, budget) not in runs:
                    continue
                a = {row["frame"]: row for row in results.rows_of(runs[first, budget])}
                b = {row["frame"]: row for row in results.rows_of(runs[second, budget])}
                frames = sorted(set(a) & set(b))
                difference, low, high = captured.paired_difference(
                    [a[f]["raster_flip"] for f in frames], [a[f]["heuristic_flip"] for f in frames],
                    [b[f]["heuristic_flip"] for f in frames], [a[f]["oracle_flip"] for f in frames])
                verdict = "not judged" if difference is None else \
                    captured.paired_verdict(first, second, difference, low, high)
                rows.append({"path": path, "budget_at": budget, "first": first, "second": second,
                             "difference": difference, "difference_lo": low, "difference_hi": high,
                             "judged_frames": len(frames), "verdict": verdict})
    return rows


def paired_markdown(rows) -> str:
    lines = ["| Path | Budget at | Variants | Captured, first - second [90%, paired] | Judged | Verdict |",
             "|---|---|---|---|---|---|"]
    for row in rows:
        interval = "" if row["difference_lo"] is None else \
            f" [{row['difference_lo']:+.2f}, {row['difference_hi']:+.2f}]"
        value = "–" if row["difference"] is None else f"{row['difference']:+.2f}"
        lines.append(f"| {row['path']} | {_number(row['budget_at'], '.2f')} | {row['first']} - {row['second']} | "
                     f"{value}{interval} | {row['judged_frames']} | {row['verdict']} |")
    return "\n".join(lines) + "\n"


def _max_flips(run_dir: Path):
    """The most flips one element made in 10 consecutive frames of a run ("" without its log)."""
    from phrt.phrt_addon.runs import run_files
    from phrt.phrt_addon.runs.summary import max_flips_in_window
    if not (run_dir / "selection.csv").is_file():
        return ""
    return max_flips_in_window(run_files.iter_selection(run_dir), 10)


def _number(text, spec):
    return "–" if text in ("", None) else format(float(text), spec)


def _percent(text):
    return "–" if text in ("", None) else f"{100 * float(text):.1f}%"


def markdown(table) -> str:
    lines = ["| Path | Variant | Budget at | Budget ms | Captured [90%] | Judged | LDR-FLIP | Popping / 100 frames "
             "| of which items | Flips / 100 frames | Max flips in 10 frames | p95 / budget | raster p95 / budget | Within budget "
             "| G-buffer ms / raster run's | T / oracle's capacity | Oracle removes |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in table:
        interval = (f" [{_number(row['captured_lo'], '.2f')}, {_number(row['captured_hi'], '.2f')}]"
                    if row["captured_lo"] not in ("", None) else "")
        within = "–" if row["within_budget"] in ("", None) else f"{100 * float(row['within_budget']):.0f}%"
        lines.append(f"| {row['path']} | {row['variant']} | {_number(row['budget_at'], '.2f')} | "
                     f"{_number(row['budget_ms'], '.0f')} | {_number(row['captured'], '.2f')}{interval} | "
                     f"{row['judged_frames']} | {_number(row['flip'], '.4f')} | {_number(row['popping'], '.1f')} | "
                     f"{_number(row.get('item_popping'), '.1f')} | {_number(row.get('flips_per_100'), '.1f')} | "
                     f"{row.get('max_flips_10', '')} | "
                     f"{_number(row['p95_over_budget'], '.2f')} | {_number(row.get('raster_p95_over_budget'), '.2f')} | "
                     f"{within} | {_number(row.get('speed_vs_raster'), '.2f')} | "
                     f"{_number(row.get('time_left_share'), '.2f')} | {_percent(row.get('oracle_reduction'))} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="PHRT selection evaluation on the judged paths")
    parser.add_argument("--out", default="out/selection-eval")
    parser.add_argument("--frames", default="1-240")
    parser.add_argument("--paths", default=DEFAULT_PATHS)
    parser.add_argument("--budget-at", default=DEFAULT_BUDGETS)
    parser.add_argument("--variants", default=DEFAULT_VARIANTS)
    parser.add_argument("--oracle-every", type=int, default=4)
    parser.add_argument("--resolution", default="320x240")
    parser.add_argument("--one-after-another", action="store_true",
                        help="run the hybrid runs one after the other, not in lockstep (phrt sweep --lockstep: "
                             "every budget and variant of a path rendered frame by frame together, so that they "
                             "meet the machine in the same state)")
    parser.add_argument("--table-only", action="store_true",
                        help="only (re)write the table from the sweeps already in --out")
    args = parser.parse_args(argv)
    try:
        table = evaluate(args)
    except EvaluationInterrupted as stop:
        print("selection-eval: stopped; run the same command again to resume (complete sweeps are reused)",
              file=sys.stderr)
        return stop.status
    write_table(Path(args.out), "selection_eval", COLUMNS, table, markdown(table))
    pairs = paired(table, Path(args.out))
    write_table(Path(args.out), "selection_eval_paired", PAIRED_COLUMNS, pairs, paired_markdown(pairs))
    return 0


def write_table(out: Path, stem: str, columns, rows, text: str) -> None:
    """``OUT/<stem>.csv`` (``columns``, one row per dict) and ``OUT/<stem>.md`` (``text``), printed."""
    with open(out / f"{stem}.csv", "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, lineterminator="\n", extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    (out / f"{stem}.md").write_text(text, encoding="utf-8")
    print(text)
    print(f"wrote {out / (stem + '.csv')} and {out / (stem + '.md')}")


if __name__ == "__main__":
    sys.exit(main())
