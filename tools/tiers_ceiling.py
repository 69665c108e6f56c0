"""``make tiers-ceiling``: the most any choice of rates could buy at a budget (issue 23's ceiling).

For each path of a selection evaluation (``tools/selection_eval.py``'s folder: its plan, runs and
oracle), every ``--every``-th frame is rendered through the real engine (HYBRID, the oracle's
``ForcedRenderer``) with each (element, effect) item of the frame's competing candidates traced
alone at full, half and quarter rate (3 timings each, on the runs' clock as the oracle's are:
``oracle_fit.Clock``), and, per budget, two combinations are chosen exactly within the budget's
nominal time for tracing (``report/tiers_ceiling.py``) and rendered, held to their measured time
(``oracle_fit.feasible_choice``):

- ``items``: (element, effect) items at full rate only (what `benefit` can buy);
- ``ceiling``: every item at any rate (what `tiers` could buy at best; shadows too).

Their LDR-FLIP against the reference is set beside the runs' (``oracle/regret.csv``: the paper's
heuristic, `benefit`, `tiers`, the element oracle) on the same frames.  Writes
``OUT/tiers_ceiling_frames.csv`` (one row per path, budget and frame) and ``OUT/tiers_ceiling.md``
(per path and budget: mean LDR-FLIP of each, and the ceiling / `benefit` ratio of means with a
90% bootstrap interval over frames).  Issue 23 asks `tiers` for a mean LDR-FLIP 20% below
`benefit`'s: where even the ceiling's ratio stays above 0.8, no choice of rates reaches it.

    python tools/tiers_ceiling.py --eval out/selection-eval-18f [--out out/tiers-ceiling]
        [--every 8] [--budget-at 0.1,0.25] [--paths atrium-path3,...]
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from pathlib import Path

import numpy as np

RUNS = ("measured", "benefit", "tiers")
COLUMNS = ("path", "budget_at", "frame", "capacity_ms", "raster_flip", "oracle_flip") + tuple(
    f"{run}_flip" for run in RUNS) + ("items_flip", "items_ms", "items_refits", "ceiling_flip", "ceiling_ms", "ceiling_refits",
                                      "n_items", "ceiling")
ITEM_COLUMNS = ("path", "frame", "element", "effect", "rate", "cost_ms", "overhead_ms", "benefit")
BOOTSTRAP = 2000


def _runs(folder: Path, label: str, plan: dict) -> dict:
    runs = {}
    for job in plan["jobs"]:
        if job.get("kind") == "run" and job.get("mode") == "HYBRID" and job.get("variant") in RUNS:
            run_dir = folder / job["id"]
            summary = json.loads((run_dir / "summary.json").read_text())
            runs[job["id"]] = {"budget_at": float(job["budget_at"]), "variant": job["variant"],
                               "budget_ms": float(summary["budget_ms"])}
    return runs


def _regret(folder: Path) -> dict:
    """{(run, frame): row} of the evaluation's oracle."""
    from phrt.phrt_addon.report import oracle
    rows = oracle.read_csv(folder / oracle.ORACLE_DIR / oracle.REGRET_CSV)
    return {(row["run"], int(row["frame"])): row for row in rows}


def measure_path(folder: Path, every: int, budget_at: list, log, item_rows: list) -> list:
    from phrt.cli import blender_process
    from phrt.engine.runs import camera_path, item_measure
    from phrt.engine.runs.oracle import ForcedRenderer, competing_candidates
    from phrt.phrt_addon.report import metrics, oracle, oracle_fit, tiers_ceiling
    from phrt.phrt_addon.runs import run_files, steady
    from phrt.phrt_addon.schema import EFFECTS
    from phrt.phrt_addon.trace.rates import RATES

    plan = json.loads((folder / "plan.json").read_text())
    label = folder.name
    blender_process.load_scene(plan["scene"])
    import bpy
    scene = bpy.context.scene
    camera = camera_path.find_path(scene, plan["path"])
    reference_dir = folder / f"{label}-raytrace"
    raster_dir = folder / f"{label}-raster-group"
    if not raster_dir.is_dir():
        raster_dir = folder / f"{label}-raster"
    raster_rows = run_files.read_frames(raster_dir)
    shared_of = oracle.shared_ms(raster_rows)
    gbuffer_of = {row["frame"]: row.get("gbuffer_ms") for row in steady.steady_rows(raster_rows)}
    runs = _runs(folder, label, plan)
    regret = _regret(folder)
    budgets = {}
    for at in budget_at:
        found = [run["budget_ms"] for run in runs.values() if abs(run["budget_at"] - at) < 1e-9]
        if not found:
            raise LookupError(f"{label} has no hybrid run at {at:g} of the way (--budget-at)")
        budgets[at] = min(found)  # never more time than a run it is compared with had
    frames = oracle.sampled_frames([row["frame"] for row in run_files.read_frames(reference_dir)], every)
    clock = oracle_fit.Clock()
    rows = []
    with ForcedRenderer(scene, camera, tuple(plan["resolution"])) as renderer, item_measure.ItemScope() as scope:
        for frame in frames:
            reference_path = run_files.frame_image_path(reference_dir, frame)
            if reference_path is None:
                continue
            reference = metrics.read_image(reference_path)
            base = renderer.raster_frame(frame, reference, clock, gbuffer_of, shared_of)  # the oracle's clock
            selection, ratio, flip_raster, shared = base.selection, base.ratio, base.flip, base.shared_ms
            names = competing_candidates(selection)
            index = {name: position for position, name in enumerate(selection.names)}
            elements = selection.elements
            items = [(name, effect) for name in names for effect in EFFECTS
                     if bool(np.asarray(getattr(elements, effect))[index[name]])]
            cost = np.full((len(items), len(RATES)), np.inf)
            benefit = np.zeros((len(items), len(RATES)))
            flips = np.zeros((len(items), len(RATES)))
            for row, (element, effect) in enumerate(items):
                for option, rate in enumerate(RATES):
                    traced = item_measure.measure_subset(renderer, frame, scope.trace_only({element: (effect,)}),
                                                         reference, rates={effect: {element: rate}})
                    cost[row, option] = traced.trace_ms / ratio
                    flips[row, option] = traced.flip
                    benefit[row, option] = flip_raster - traced.flip
            overhead = 0.0
            if len(items) > 1:  # all together at full rate: the trace stage's fixed part, paid once
                scope.trace_only({})
                together = item_measure.measure_subset(renderer, frame, names, reference)
                overhead = oracle.trace_overhead_ms(cost[:, -1], together.trace_ms / ratio)
            found = tiers_ceiling.TierCandidates(frame=frame, items=items, rates=tuple(RATES),
                                                 cost_ms=np.maximum(cost - overhead, 0.0), benefit=benefit,
                                                 flip_raster=flip_raster, overhead_ms=overhead)
            item_rows += [{"path": label, "frame": frame, "element": element, "effect": effect, "rate": rate,
                           "cost_ms": found.cost_ms[row, option], "overhead_ms": overhead,
                           "benefit": benefit[row, option]}
                          for row, (element, effect) in enumerate(items) for option, rate in enumerate(RATES)]
            full_only = np.zeros(cost.shape, bool)
            full_only[:, -1] = True
            # What each choice may fall back on (feasible_choice): subsets measured, those of full-rate
            # items only for the items' choice (the ceiling may take them too).
            singles = {frozenset([(*item, rate)]): (float(cost[row, option]), float(flips[row, option]))
                       for row, item in enumerate(items) for option, rate in enumerate(RATES)}
            full_rate = {frozenset(): (0.0, flip_raster)}
            full_rate.update({chosen: value for chosen, value in singles.items() if next(iter(chosen))[2] == 1.0})
            rendered = {**full_rate, **singles}

            def measure(chosen):
                effects_of, rates = {}, {}
                for element, effect, rate in chosen:
                    effects_of.setdefault(element, []).append(effect)
                    rates.setdefault(effect, {})[element] = rate
                traced = item_measure.measure_subset(renderer, frame, scope.trace_only(effects_of), reference,
                                                     rates=rates)
                return traced.trace_ms / ratio, traced.flip

            for at, budget in budgets.items():
                capacity = oracle.nominal_time_left(budget, shared)
                found.allowed = full_only
                chosen_items, items_refits = oracle_fit.feasible_choice(found, capacity, budget, measure, full_rate)
                found.allowed = None
                rendered.update(full_rate)
                ceiling, refits = oracle_fit.feasible_choice(found, capacity, budget, measure, rendered)
                full_rate.update({chosen: value for chosen, value in rendered.items()
                                  if all(rate == 1.0 for _, _, rate in chosen)})
                row = {"path": label, "budget_at": at, "frame": frame, "capacity_ms": capacity,
                       "raster_flip": flip_raster, "items_flip": full_rate[chosen_items][1],
                       "items_ms": full_rate[chosen_items][0], "items_refits": items_refits,
                       "ceiling_flip": rendered[ceiling][1],
                       "ceiling_ms": rendered[ceiling][0], "ceiling_refits": refits, "n_items": len(items),
                       "ceiling": ";".join(f"{element}:{effect}@{rate:g}" for element, effect, rate in sorted(ceiling))}
                for run_id, run in runs.items():
                    if abs(run["budget_at"] - at) < 1e-9:
                        got = regret.get((run_id, frame))
                        row[f"{run['variant']}_flip"] = float(got["heuristic_flip"]) if got else float("nan")
                        if got and run["variant"] == "benefit":
                            row["oracle_flip"] = float(got["oracle_flip"])
                rows.append(row)
            scope.trace_only({})
            log(f"{label} frame {frame}: {len(items)} items, ratio {ratio:.2f}, "
                + ", ".join(f"{row['budget_at']:g}: ceiling {row['ceiling_flip']:.4f} items {row['items_flip']:.4f} "
                            f"benefit {row.get('benefit_flip', float('nan')):.4f}" for row in rows[-len(budgets):]))
    return rows


def ratio_interval(numerator, denominator, seed=0):
    """Ratio of means and its 90% bootstrap interval over paired frames."""
    numerator, denominator = np.asarray(numerator, float), np.asarray(denominator, float)
    keep = np.isfinite(numerator) & np.isfinite(denominator)
    numerator, denominator = numerator[keep], denominator[keep]
    if len(numerator) == 0 or denominator.sum() <= 0:
        return float("nan"), float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    picks = rng.integers(0, len(numerator), (BOOTSTRAP, len(numerator)))
    ratios = numerator[picks].sum(axis=1) / np.maximum(denominator[picks].sum(axis=1), 1e-12)
    low, high = np.percentile(ratios, [5, 95])
    return float(numerator.sum() / denominator.sum()), float(low), float(high)


def markdown(rows) -> str:
    lines = ["| path | budget | frames | raster | paper | `benefit` | `tiers` | oracle (elements) | items (full rate) "
             "| ceiling (any rate) | ceiling / `benefit` [90%] | reachable (< 0.8)? |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    groups = {}
    for row in rows:
        groups.setdefault((row["path"], row["budget_at"]), []).append(row)
    for (path, at), group in groups.items():
        def mean(key):
            values = [float(row.get(key, float("nan"))) for row in group]
            values = [value for value in values if np.isfinite(value)]
            return f"{np.mean(values):.4f}" if values else "–"
        ratio, low, high = ratio_interval([row["ceiling_flip"] for row in group],
                                          [row.get("benefit_flip", float("nan")) for row in group])
        verdict = "no" if low > 0.8 else ("yes" if high < 0.8 else "not told apart")
        lines.append(f"| {path} | {at:g} | {len(group)} | {mean('raster_flip')} | {mean('measured_flip')} "
                     f"| {mean('benefit_flip')} | {mean('tiers_flip')} | {mean('oracle_flip')} | {mean('items_flip')} "
                     f"| {mean('ceiling_flip')} | {ratio:.3f} [{low:.3f}, {high:.3f}] | {verdict} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="the most any choice of rates could buy (issue 23's ceiling)")
    parser.add_argument("--eval", required=True, help="a tools/selection_eval.py folder")
    parser.add_argument("--out", default="out/tiers-ceiling")
    parser.add_argument("--every", type=int, default=8)
    parser.add_argument("--budget-at", default="0.1,0.25")
    parser.add_argument("--paths", default="", help="comma-separated path folders (default: every one)")
    args = parser.parse_args(argv)
    folder = Path(args.eval)
    paths = [folder / name for name in args.paths.split(",") if name] or sorted(
        child for child in folder.iterdir() if (child / "plan.json").is_file())
    if not paths or not all((path / "plan.json").is_file() for path in paths):
        print(f"tiers-ceiling: no evaluated path under {folder} (run tools/selection_eval.py first)", file=sys.stderr)
        return 2
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    budget_at = [float(value) for value in args.budget_at.split(",")]
    rows, item_rows = [], []
    for path in paths:
        try:
            rows += measure_path(path, args.every, budget_at, lambda text: print(text, flush=True), item_rows)
        except LookupError as error:
            print(f"tiers-ceiling: {error}", file=sys.stderr)
            return 2
        for name, columns, written in (("tiers_ceiling_frames.csv", COLUMNS, rows),
                                       ("tiers_ceiling_items.csv", ITEM_COLUMNS, item_rows)):
            with open(out / name, "w", newline="") as handle:
                writer = csv.DictWriter(handle, columns, extrasaction="ignore", restval="")
                writer.writeheader()
                writer.writerows(written)
        (out / "tiers_ceiling.md").write_text(markdown(rows))
    print((out / "tiers_ceiling.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
