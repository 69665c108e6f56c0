"""Selection quality in the report: popping per run, the oracle's regret, and the rows of ``sweep.csv``.
"""
import csv
import json
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import captured, oracle, popping
from .captured import Captured
from ..runs import atomic, run_log, steady
from .runs import METRIC_THREADS, SWEEP_COLUMNS


def measure_run_popping(runs, references):
    """{id(run): PoppingResult} for runs with images whose path has a reference with images."""
    pops = {}
    reference_maps = {}  # shared by the runs (threads may both compute a map: same value)
    measured = []
    for run in runs:
        reference = references.get(run.group)
        if reference is None or not reference.has_images or not run.has_images:
            continue
        if run is reference:
            pops[id(run)] = popping.PoppingResult(frame_count=len(run.frames))  # the reference: 0 by definition
            continue
        measured.append((run, reference))
    with ThreadPoolExecutor(METRIC_THREADS) as pool:
        results = pool.map(lambda pair: popping.measure_popping(pair[0].run_dir, pair[1].run_dir, pair[0].selection,
                                                                reference_maps), measured)
        for (run, _), result in zip(measured, results):
            pops[id(run)] = result
    return pops


def load_oracle_results(runs, oracle_dir):
    """The oracle folder's results (several folders, e.g. two sweeps, are merged)."""
    if oracle_dir is None:
        parents = {run.run_dir.resolve().parent for run in runs}
        if len(parents) != 1:
            return None
        oracle_dir = next(iter(parents)) / oracle.ORACLE_DIR
    folders = [oracle_dir] if isinstance(oracle_dir, (str, Path)) else list(oracle_dir)
    found = [results for results in map(oracle.read_results, folders) if results is not None]
    if not found:
        return None
    for results in found:  # which sweep each candidate row came from
        results.candidate_rows = [{"sweep": results.folder.resolve().parent.name, **row}
                                  for row in results.candidate_rows]
    merged = found[0]
    for results in found[1:]:
        merged.info = {**merged.info, "runs": {**merged.info.get("runs", {}), **results.info.get("runs", {})}}
        merged.regret_rows = merged.regret_rows + results.regret_rows
        merged.candidate_rows = merged.candidate_rows + results.candidate_rows
    return merged


@dataclass
class RunRegret:
    """The oracle's verdict on one hybrid run."""

    frames: int = 0
    mean: float | None = None
    max: float | None = None
    heuristic_flip: float | None = None
    oracle_flip: float | None = None
    differs: int = 0
    overran: int = 0  # judged frames whose choice cost, by the oracle's measurements, more than the budget's
    lost_share: float | None = None  # 1 - captured share
    # The run's own T over the oracle's capacity, summed over the judged frames: how much of the
    # budget's nominal time for tracing the run still had after its bookkeeping and the machine's drift.
    time_left_share: float | None = None
    # 1 - the oracle's LDR-FLIP summed over the judged frames / the raster frame's: how much of the
    # frame's error the budget can remove at all (a few percent: captured is a ratio of small differences).
    oracle_reduction: float | None = None
    judged_errors: dict = field(default_factory=dict)  # frame -> (raster, run, oracle) LDR-FLIP
    judged: Captured = field(default_factory=Captured)  # the captured share over the judged frames
    oracle_only: dict = field(default_factory=dict)
    heuristic_only: dict = field(default_factory=dict)
    note: str = ""


def run_regrets(runs, results):
    """{id(run): RunRegret} of the hybrid runs."""
    regrets = {}
    for run in runs:
        if run.mode != "HYBRID":
            continue
        if results is None:
            regrets[id(run)] = RunRegret(note="no oracle (run 'phrt sweep')")
            continue
        name = run.run_dir.name
        if not results.is_current_for(name, run.run_dir):
            note = "not in the oracle" if name not in results.runs() else "oracle is older than the run"
            regrets[id(run)] = RunRegret(note=note)
            continue
        rows = results.rows_of(name)
        if not rows:
            regrets[id(run)] = RunRegret(note="no sampled frame")
            continue
        rows = sorted(rows, key=lambda row: row["frame"])
        values = np.array([row["regret"] for row in rows], dtype=float)
        share = captured.measure([row["raster_flip"] for row in rows], [row["heuristic_flip"] for row in rows],
                                 [row["oracle_flip"] for row in rows])
        oracle_only, heuristic_only = {}, {}
        for row in rows:
            for element in row["oracle_only"]:
                oracle_only[element] = oracle_only.get(element, 0) + 1
            for element in row["heuristic_only"]:
                heuristic_only[element] = heuristic_only.get(element, 0) + 1
        regrets[id(run)] = RunRegret(
            frames=len(rows), mean=float(values.mean()), max=float(values.max()),
            heuristic_flip=float(np.mean([row["heuristic_flip"] for row in rows])),
            oracle_flip=float(np.mean([row["oracle_flip"] for row in rows])),
            differs=sum(1 for row in rows if set(row["oracle"]) != set(row["heuristic"])),
            overran=sum(1 for row in rows if row["capacity_ms"] is not None and row["heuristic_cost_ms"] is not None
                        and row["heuristic_cost_ms"] > row["capacity_ms"] + 1e-9),
            lost_share=None if share.share is None else 1.0 - share.share,
            time_left_share=time_left_share(rows), oracle_reduction=oracle_reduction(rows),
            judged_errors={row["frame"]: (row["raster_flip"], row["heuristic_flip"], row["oracle_flip"]) for row in rows},
            oracle_only=oracle_only, heuristic_only=heuristic_only, judged=share)
    return regrets


def oracle_reduction(rows) -> float | None:
    """1 - sum of the oracle's LDR-FLIP / sum of the raster frame's over ``rows`` (regret rows); None
    without raster error."""
    raster = float(np.sum([row["raster_flip"] for row in rows]))
    if not raster > 0.0:
        return None
    return 1.0 - float(np.sum([row["oracle_flip"] for row in rows])) / raster


def time_left_share(rows) -> float | None:
    """Sum of the runs' T over the sum of the oracle's capacity on the frames that have both
    (None when the capacity sums to 0: nothing to share)."""
    pairs = [(row["time_left_ms"], row["capacity_ms"]) for row in rows
             if row.get("time_left_ms") is not None and row.get("capacity_ms") is not None]
    capacity = float(sum(pair[1] for pair in pairs))
    return float(sum(pair[0] for pair in pairs)) / capacity if capacity > 0 else None


def variant_label(variant) -> str:
    """A short name of a selection variant: the paper's heuristic and what differs from it."""
    cost_mode, weight, order, relevance, selection = (tuple(variant) + ("paper",))[:5]
    if selection.startswith("benefit"):  # the (element, effect) items: R, I and the order play no part
        return "BENEFIT items, quality tiers" if selection == "benefit+tiers" else "BENEFIT items"
    parts = ["error-aware R" if relevance == "error" else "paper R"]
    parts.append(f"{cost_mode} cost")
    parts.append(f"I={weight:g}")
    if order == "relevance_per_ms":
        parts.append("R/ms order")
    return ", ".join(parts)


def sweep_rows(runs, errors, regrets, pops, references):
    """One dict per run with the keys of SWEEP_COLUMNS (None where not applicable)."""
    rows = []
    for run in runs:
        outcome = errors[id(run)]
        raster = next((other for other in runs if other.mode == "RASTER" and other.scene == run.scene
                       and other.path == run.path and all(other.summary.get(key) == run.summary.get(key)
                                                          for key in ("resolution", "frame_range"))), None)
        regret = regrets.get(id(run))
        pop = pops.get(id(run))
        hybrid = run.mode == "HYBRID"
        rates = np.array(list(run.selection.flips_per_element_per_100().values()), dtype=float)
        cost_mode, weight, order, relevance = run.variant[:4]
        share = regret.judged if regret is not None else Captured()
        budget_ms = run.summary.get("budget_ms") if hybrid else None
        rows.append({
            "run": run.label, "mode": run.mode, "cost_mode": cost_mode if hybrid else None,
            "budget_ms": budget_ms, "mean_ms": run.steady("mean"), "p95_ms": run.steady("p95"),
            "flip": outcome.mean("flip"), "relmse": outcome.mean("relmse"), "psnr": outcome.mean("psnr_db"),
            "regret": regret.mean if regret is not None else None,
            "flips_per_100": float(rates.mean()) if rates.size else 0.0,
            "popping": pop.per_100_frames() if pop is not None else None,
            "item_popping": pop.per_100_frames("items") if pop is not None else None,
            "scene": run.scene, "path": run.path,
            "variant": variant_label(run.variant) if hybrid else run.mode.lower(),
            "budget_at": run.budget_at if hybrid else None,
            "selection_weight": weight if hybrid else None, "selection_order": order if hybrid else None,
            "relevance": relevance if hybrid else None, "frames": len(run.frames),
            "mean_selected": run.mean("n_selected"),
            "regret_frames": regret.frames if regret is not None else None,
            "regret_share": regret.lost_share if regret is not None else None,
            "captured": share.share, "captured_lo": share.low, "captured_hi": share.high,
            "judged_frames": share.judged_frames if regret is not None else None,
            "min_regret": share.min_regret, "beat_oracle": share.beat_oracle if regret is not None else None,
            "p95_over_budget": steady.over_budget(run.steady("p95"), budget_ms),
            "within_budget": run.within_budget() if hybrid else None,
            "first_frame_ms": run.first_frame_ms, "variant_name": run.variant_name,
            "speed_vs_raster": steady.speed_against(run.frames, raster.frames)
            if raster is not None and raster is not run else None,
            "time_left_share": regret.time_left_share if regret is not None else None,
            "lockstep_runs": run.summary.get("lockstep_runs"),
            "oracle_reduction": regret.oracle_reduction if regret is not None else None,
            # Not a column: the judged frames' errors, for the paired verdicts (results.verdicts).
            "judged_errors": regret.judged_errors if regret is not None else None,
        })
    return rows


def write_sweep(csv_path, json_path, rows, oracle_results):
    with atomic.atomic_open(csv_path, "w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(SWEEP_COLUMNS)
        for row in rows:
            writer.writerow([run_log.format_value(row[key]) for key in SWEEP_COLUMNS])
    document = {"columns": list(SWEEP_COLUMNS), "runs": [{key: row[key] for key in SWEEP_COLUMNS} for row in rows],
                "oracle": None if oracle_results is None else {
                    "every": oracle_results.info.get("every"), "frames": oracle_results.info.get("frames"),
                    "note": oracle_results.info.get("note")}}
    document = run_log.json_ready(document)
    atomic.write_text(json_path, json.dumps(document, indent=2, allow_nan=False) + "\n")
