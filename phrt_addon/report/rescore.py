"""Offline rescoring (``phrt rescore SWEEP_DIR``): a sweep's recorded choices judged again on the
oracle's measurements, without rendering anything.

For every hybrid run the oracle judged and each of its judged frames, the
run's choice (``selected`` in its ``selection.csv``) is priced and valued with
what the oracle measured on that frame (``oracle/candidates.csv``: each
candidate's median trace cost and its own error drop), and set against the
oracle's subset for the same budget (``oracle/regret.csv``):

- ``captured_additive`` (with ``_lo`` / ``_hi``, the 90% interval of
  ``captured.py``): the share of the oracle's summed benefit the run's choice
  sums to, benefits taken as adding up (the rendered ``captured`` of
  ``sweep.csv`` measures the images; the two differ by the elements'
  interactions);
- ``own_time_additive``: the same share reached by the best subset (the oracle's knapsack on its
  measurements) within the time the run itself kept for tracing on each frame (its ``time_left_ms``)
  rather than the budget's nominal time: what a perfect choice could have captured in the run's
  time (None when a judged frame did not record its time left).  It splits a run's shortfall in
  two: below it, the choice; its own shortfall from 1, the time (the raster half's noise, the
  selection's own bookkeeping, a slower machine state; above 1, a run that had more time than the
  nominal one).  Under ``BENEFIT`` the time left is the paper's T, before the aim and the margin
  the knapsack then applies;
- ``over_capacity_frames`` and ``mean_cost_share``: frames whose choice costs,
  by the oracle's measurements, more than the budget's nominal time for
  tracing, and the mean measured cost / that time;
- when the run recorded them (``selection.csv`` columns ``predicted_ms`` and
  ``benefit``): ``median_predicted_over_measured`` (the selection's predicted
  cost of its choice over the oracle's measured cost) and
  ``benefit_rank_correlation`` (Spearman, over every judged candidate: how well
  the selection's benefit estimate orders what the oracle measured; under
  ``BENEFIT`` the estimate is weighted by K / Q, as the choice weighed it).

Writes ``rescore.csv`` and ``rescore.md``.  Plain Python + numpy, no ``bpy``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .. import schema
from ..runs import run_files
from . import captured, oracle

RESCORE_CSV = "rescore.csv"
RESCORE_MD = "rescore.md"
RESCORE_COLUMNS = ("run", "budget_ms", "judged_frames", "captured_additive", "captured_additive_lo",
                   "captured_additive_hi", "own_time_additive", "over_capacity_frames", "mean_cost_share",
                   "median_predicted_over_measured", "benefit_rank_correlation")


def _frame_candidates(candidate_rows) -> dict:
    """{frame: FrameCandidates} from ``candidates.csv`` rows."""
    by_frame = {}
    for row in candidate_rows:
        by_frame.setdefault(int(row["frame"]), []).append(row)
    frames = {}
    for frame, rows in by_frame.items():
        frames[frame] = oracle.FrameCandidates(
            frame=frame, names=[row["element"] for row in rows],
            cost_ms=np.array([float(row["cost_ms"]) for row in rows]),
            benefit=np.array([float(row["benefit"]) for row in rows]),
            flip_raster=float(rows[0]["flip_raster"]), overhead_ms=float(rows[0]["overhead_ms"] or 0.0))
    return frames


def _ranks(values):
    order = np.argsort(values, kind="stable")
    ranks = np.empty(len(values))
    ranks[order] = np.arange(len(values))
    return ranks


def spearman(first, second) -> float | None:
    """Spearman's rank correlation (None with fewer than 3 pairs or a constant side)."""
    first, second = np.asarray(first, dtype=float), np.asarray(second, dtype=float)
    if first.size < 3 or np.ptp(first) == 0 or np.ptp(second) == 0:
        return None
    return float(np.corrcoef(_ranks(first), _ranks(second))[0, 1])


def rescore_run(run_dir, rows, frames) -> dict:
    """The rescore row of one run: ``rows`` its regret rows, ``frames`` {frame: FrameCandidates}."""
    selection = {}
    for row in run_files.read_selection(run_dir):
        selection.setdefault(int(row["frame"]), []).append(row)
    raster, chosen, best, in_own_time, costs, ratios, estimates, truths = [], [], [], [], [], [], [], []
    over = 0
    for row in sorted(rows, key=lambda row: row["frame"]):
        frame = frames.get(row["frame"])
        if frame is None:
            continue
        recorded = selection.get(row["frame"], [])
        picked = {str(item["element"]) for item in recorded if item["selected"]}
        cost, benefit = frame.totals(picked)
        _, oracle_benefit = frame.totals(row["oracle"])
        raster.append(frame.flip_raster)
        chosen.append(frame.flip_raster - benefit)
        best.append(frame.flip_raster - oracle_benefit)
        own_ms = row.get("time_left_ms")
        if own_ms is None or np.isnan(own_ms):
            in_own_time.append(None)  # not recorded: the own-time share is not given
        else:  # unlimited time: every candidate
            own_ms = min(float(own_ms), float(np.sum(frame.cost_ms)) + frame.overhead_ms)
            in_own_time.append(frame.flip_raster - frame.totals(frame.choose(own_ms))[1])
        capacity = row["capacity_ms"] or 0.0
        over += int(cost > capacity + 1e-9)
        if capacity > 0:
            costs.append(cost / capacity)
        predicted = [item.get("predicted_ms") for item in recorded if item["selected"]]
        if picked and predicted and all(value is not None for value in predicted) and cost > 0:
            ratios.append(float(np.sum(predicted)) / cost)
        measured = dict(zip(frame.names, frame.benefit.tolist()))
        for item in recorded:
            if item.get("benefit") is not None and str(item["element"]) in measured:
                estimates.append(float(item["benefit"]))
                truths.append(measured[str(item["element"])])
    result = captured.measure(raster, chosen, best)
    own_time = captured.measure(raster, in_own_time, best) if all(value is not None for value in in_own_time) \
        else None
    return {"run": Path(run_dir).name, "budget_ms": rows[0]["budget_ms"] if rows else None,
            "judged_frames": result.judged_frames, "captured_additive": result.share,
            "captured_additive_lo": result.low, "captured_additive_hi": result.high,
            "own_time_additive": own_time.share if own_time is not None else None,
            "over_capacity_frames": over, "mean_cost_share": float(np.mean(costs)) if costs else None,
            "median_predicted_over_measured": float(np.median(ratios)) if ratios else None,
            "benefit_rank_correlation": spearman(estimates, truths)}


def rescore(sweep_dir, out_dir=None) -> tuple[list, Path]:
    """Rescore every run the sweep's oracle judged; returns (rows, folder written).  ``ValueError``
    for the user when the folder holds no complete oracle."""
    sweep_dir = Path(sweep_dir)
    results = oracle.read_results(sweep_dir / oracle.ORACLE_DIR)
    if results is None:
        raise ValueError(f"{sweep_dir} holds no complete {oracle.ORACLE_DIR}/{oracle.ORACLE_JSON}: give a folder "
                         f"written by 'phrt sweep' whose oracle finished")
    frames = _frame_candidates(results.candidate_rows)
    rows = []
    for label in results.runs():
        run_dir = sweep_dir / label
        if (run_dir / schema.SELECTION_CSV).is_file():
            rows.append(rescore_run(run_dir, results.rows_of(label), frames))
    out_dir = Path(out_dir) if out_dir is not None else sweep_dir / "report"
    out_dir.mkdir(parents=True, exist_ok=True)
    oracle.write_csv(out_dir / RESCORE_CSV, RESCORE_COLUMNS, rows)
    (out_dir / RESCORE_MD).write_text(markdown(rows), encoding="utf-8")
    return rows, out_dir


def _cell(value, spec):
    return "–" if value is None else format(value, spec)


def markdown(rows) -> str:
    """The rescore table as Markdown (numbers rounded to what they can mean)."""
    lines = ["# Rescored choices (oracle measurements, no rendering)", "",
             "| Run | Budget ms | Judged frames | Captured (additive) [90%] | Best in its own time | Over capacity "
             "| Cost / capacity | Predicted / measured | Benefit rank corr. |", "|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        interval = (f" [{row['captured_additive_lo']:.2f}, {row['captured_additive_hi']:.2f}]"
                    if row["captured_additive_lo"] is not None else "")
        lines.append(f"| {row['run']} | {_cell(row['budget_ms'], '.0f')} | {row['judged_frames']} | "
                     f"{_cell(row['captured_additive'], '.2f')}{interval} | {_cell(row['own_time_additive'], '.2f')} | "
                     f"{row['over_capacity_frames']} | "
                     f"{_cell(row['mean_cost_share'], '.2f')} | {_cell(row['median_predicted_over_measured'], '.2f')} | "
                     f"{_cell(row['benefit_rank_correlation'], '.2f')} |")
    return "\n".join(lines) + "\n"
