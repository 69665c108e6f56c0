"""The oracle selection and each run's regret against it (outside every timed region).

On sampled frames (every ``k``-th frame of the runs, default 8) the oracle
(``engine/runs/oracle.py`` renders, this module decides and keeps the books):

1. renders the frame with nothing traced (the raster image of the frame) and
   with each visible candidate traced alone, and measures against the
   reference (raytrace) run's image of the same frame
   - its **benefit**: mean LDR-FLIP of the raster frame minus that of the frame
     with the element traced alone (its own error drop), and
   - its **cost**: the median of :data:`TIMINGS` timings of the trace stage
     when traced alone (without one-time Embree uploads; one timing would
     hand the oracle a winner's curse: the luckiest timing of each element),
     less the trace stage's fixed part, which a frame pays once whatever it
     traces (``overhead_ms``: how much the candidates traced alone cost more,
     summed, than all of them traced together, per extra trace); a subset
     costs its elements' costs plus that fixed part; every timing on the
     runs' clock (``oracle_fit.Clock``: divided by how much slower the
     machine ran than during the runs, from the G-buffer pass);
2. **one oracle per budget**, the same for every variant at that budget: its
   time for tracing (``capacity_ms``) is the budget's nominal time left on
   that frame, ``budget_ms - shared_ms``, where ``shared_ms`` is what every
   variant spends on that frame whatever it selects: the raster run's
   ``raster_ms + select_ms + composite_ms`` on that frame (:func:`shared_ms`; the
   steady median for its first frame).  Every mode does that selection (each
   element's pixels, the log's terms): at 0 of the way the oracle has no time.
   A variant's own bookkeeping beyond it is part of what it costs; nor is a
   run's own T shared (``time_left_ms``, kept beside for
   reading): a run that overran, or whose bookkeeping shrank T, is judged on
   the same scale as the others.  Within it, the subset of candidates with
   the largest summed benefit: an exact 0/1 knapsack on measured numbers
   (:func:`knapsack`, branch and bound);
3. renders that subset (always: with an ample budget the oracle's image is
   rendered and measured too, never copied from the run) and measures its
   error and its own trace time (``oracle_trace_ms``, the median of TIMINGS,
   beside its predicted ``oracle_cost_ms``); a subset whose trace is over its
   time is chosen again (``oracle_fit``, ``oracle_refits``):
   ``regret = error(run) - error(oracle)``, the run's error being that of its
   own image.

The oracle measures error, unweighted: the designer's priority K says what
the designer wants traced first and steers a selection, but the yardstick is
the error against the reference, the same for every element (a K-weighted
oracle would reward a selection for agreeing with K, not for lowering error).

Benefits below ``MIN_BENEFIT`` are raised to it: tracing an element never moves
the frame away from the reference, which traces it too, so a measured drop at
or below zero is FLIP noise (and a budget that covers every candidate then
traces them all, as the reference does).  Benefits add up only
approximately (a reflection may show another traced element), which is why the
chosen subset is rendered and measured rather than its predicted error
trusted; a run may therefore beat the oracle on a frame (negative regret,
counted by the report).  ``report/captured.py`` turns the rows into the share
of the oracle's error reduction each run captures.

Files in the oracle folder (``ORACLE_DIR`` of a sweep): ``candidates.csv`` (one
row per sampled frame and candidate), ``regret.csv`` (one row per hybrid run
and sampled frame) and ``oracle.json`` (settings, per-run means, and the hash
of each run's ``summary.json`` it was computed from, so a redone run makes it
stale).  Plain Python + numpy, no ``bpy``.
"""
from __future__ import annotations

import csv
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..runs import run_log
from ..runs import steady
from .. import schema
from ..runs import atomic

ORACLE_DIR = "oracle"
ORACLE_JSON = "oracle.json"
CANDIDATES_CSV = "candidates.csv"
REGRET_CSV = "regret.csv"
DEFAULT_EVERY = 8
MIN_BENEFIT = 1e-6
# Timings of each candidate traced alone (and of all together); the cost is their median.
TIMINGS = 3
CANDIDATE_COLUMNS = ("frame", "element", "area_px", "cost_ms", "cost_spread_ms", "overhead_ms", "flip_alone",
                     "flip_raster", "benefit")
REGRET_COLUMNS = ("run", "frame", "budget_ms", "shared_ms", "capacity_ms", "time_left_ms", "raster_flip",
                  "heuristic_flip", "oracle_flip", "regret", "heuristic", "oracle", "oracle_only", "heuristic_only",
                  "oracle_cost_ms", "oracle_trace_ms", "heuristic_cost_ms", "oracle_benefit", "heuristic_benefit",
                  "oracle_refits")
REGRET_FLOATS = ("budget_ms", "shared_ms", "capacity_ms", "time_left_ms", "raster_flip", "heuristic_flip",
                 "oracle_flip", "regret", "oracle_cost_ms", "oracle_trace_ms", "heuristic_cost_ms", "oracle_benefit",
                 "heuristic_benefit")
# Knapsack search nodes before giving up exactness (never reached with a frame's candidates).
MAX_NODES = 2_000_000


# Candidates the oracle judges per sampled frame (each costs a render): the most valuable by the
# selection's own estimate, plus a few drawn at random from the rest (what the estimate misjudges).
MAX_CANDIDATES = 48
RANDOM_CANDIDATES = 8


def cap_candidates(names, estimates, cap: int = MAX_CANDIDATES, random_extra: int = RANDOM_CANDIDATES,
                   seed: int = 0) -> tuple[list, bool]:
    """At most ``cap`` of ``names``: the ``cap - random_extra`` with the largest ``estimates`` (the
    selection's relevance R), then ``random_extra`` drawn from the others (``seed``: the frame, so
    a rerun judges the same ones), in their original order; and whether any was left out."""
    names = list(names)
    if cap < 1:
        raise ValueError(f"the oracle needs to judge at least 1 candidate per frame, not {cap}")
    if len(names) <= cap:
        return names, False
    values = np.nan_to_num(np.asarray(estimates, dtype=np.float64), nan=-np.inf)
    top = max(cap - max(random_extra, 0), 0)
    order = np.argsort(-values, kind="stable")
    kept = set(order[:top].tolist())
    rest = np.array(sorted(set(range(len(names))) - kept))
    drawn = np.random.default_rng(seed).choice(rest, size=min(cap - top, len(rest)), replace=False)
    kept.update(drawn.tolist())
    return [names[index] for index in sorted(kept)], True


def sampled_frames(frames, every: int = DEFAULT_EVERY) -> list[int]:
    """Every ``every``-th of ``frames`` (sorted): the k-th, 2k-th, ... frame of the run, so the
    first frame (cold cost model, one-time set-up) is judged only in runs shorter than k."""
    if every < 1:
        raise ValueError(f"oracle sampling must be every k >= 1 frames, not {every}")
    ordered = sorted(set(int(frame) for frame in frames))
    return ordered[every - 1::every] or ordered[-1:]


def knapsack(values, costs, capacity: float) -> np.ndarray:
    """Exact 0/1 knapsack: the mask of items maximising the summed ``values`` with summed
    ``costs`` <= ``capacity`` (floats).  Depth-first branch and bound in value-per-cost
    order with the fractional (Dantzig) bound; among equal values the cheaper set and then
    the earlier items win.  Items with cost <= 0 and value > 0 are always taken."""
    values = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0)
    costs = np.nan_to_num(np.asarray(costs, dtype=np.float64), nan=np.inf, posinf=np.inf)
    n = len(values)
    chosen = np.zeros(n, dtype=bool)
    capacity = float(capacity) if np.isfinite(capacity) else np.inf
    if n == 0 or capacity < 0:
        return chosen
    free = (costs <= 0) & (values > 0)
    chosen[free] = True
    useful = np.flatnonzero(~free & (values > 0) & (costs <= capacity))
    if len(useful) == 0:
        return chosen
    if np.isinf(capacity) or costs[useful].sum() <= capacity:
        chosen[useful] = True
        return chosen
    ratio = values[useful] / costs[useful]
    order = useful[np.lexsort((useful, costs[useful], -ratio))]
    item_values, item_costs = values[order].tolist(), costs[order].tolist()
    m = len(order)
    best = {"value": -1.0, "cost": np.inf, "set": []}
    current = []
    nodes = 0

    def bound(index, room, value):
        for position in range(index, m):
            if item_costs[position] <= room:
                room -= item_costs[position]
                value += item_values[position]
            else:
                return value + item_values[position] * room / item_costs[position]
        return value

    def search(index, room, value, spent):
        nonlocal nodes
        nodes += 1
        if value > best["value"] + 1e-15 or (abs(value - best["value"]) <= 1e-15 and spent < best["cost"]):
            best.update(value=value, cost=spent, set=list(current))
        if index == m or nodes > MAX_NODES:
            return
        if bound(index, room, value) <= best["value"] + 1e-15:
            return
        if item_costs[index] <= room:
            current.append(index)
            search(index + 1, room - item_costs[index], value + item_values[index], spent + item_costs[index])
            current.pop()
        search(index + 1, room, value, spent)

    search(0, capacity, 0.0, 0.0)
    chosen[order[best["set"]]] = True
    return chosen


@dataclass
class FrameCandidates:
    """The measured candidates of one sampled frame."""

    frame: int
    names: list
    cost_ms: np.ndarray
    benefit: np.ndarray
    flip_raster: float
    flip_alone: np.ndarray = field(default_factory=lambda: np.zeros(0))
    area_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    overhead_ms: float = 0.0
    cost_spread_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))  # max - min of the timings

    def choose(self, capacity_ms: float) -> frozenset:
        """The oracle's subset for ``capacity_ms`` of tracing (the fixed part paid once)."""
        room = float(capacity_ms) - self.overhead_ms
        if room < 0:
            return frozenset()
        mask = knapsack(np.maximum(self.benefit, MIN_BENEFIT), self.cost_ms, room)
        return frozenset(name for name, taken in zip(self.names, mask.tolist()) if taken)

    def totals(self, names) -> tuple[float, float]:
        """(cost ms, summed benefit) of a subset (names outside the candidates count 0); a
        non-empty subset pays the fixed part once."""
        index = {name: position for position, name in enumerate(self.names)}
        rows = [index[name] for name in names if name in index]
        fixed = self.overhead_ms if rows else 0.0
        return (float(np.sum(self.cost_ms[rows])) + fixed,
                float(np.sum(np.maximum(self.benefit[rows], MIN_BENEFIT))))


def trace_overhead_ms(alone_ms, together_ms) -> float:
    """The trace stage's fixed part from the costs of n candidates traced alone and of all of
    them together: (sum alone - together) / (n - 1), within [0, the cheapest alone]."""
    alone = np.asarray(alone_ms, dtype=np.float64)
    if len(alone) < 2 or not np.isfinite(together_ms):
        return 0.0
    return float(np.clip((alone.sum() - float(together_ms)) / (len(alone) - 1), 0.0, alone.min()))


def shared_ms(raster_rows) -> dict:
    """{frame: ms every variant spends on it whatever it selects}: the raster run's ``raster_ms +
    select_ms + composite_ms`` of each frame (no ``select_ms``: 0); its first frame (one-time
    work) and frames without raster and composite ms get the median over its steady frames."""
    def both(row):
        values = [row.get("raster_ms"), row.get("composite_ms")]
        select = row.get("select_ms")
        return None if any(value is None or not np.isfinite(value) for value in values) else \
            float(sum(values)) + (float(select) if select is not None and np.isfinite(select) else 0.0)

    rows = sorted(raster_rows, key=lambda row: int(row["frame"]))
    own = {int(row["frame"]): both(row) for row in steady.steady_rows(rows)}
    typical = [value for value in own.values() if value is not None]
    fallback = float(np.median(typical)) if typical else None
    return {int(row["frame"]): own[int(row["frame"])] if own.get(int(row["frame"])) is not None else fallback
            for row in rows}


def nominal_time_left(budget_ms, shared) -> float:
    """The budget's nominal time for tracing on a frame: budget minus the shared part (>= 0)."""
    if budget_ms is None or shared is None:
        return 0.0
    return max(float(budget_ms) - float(shared), 0.0)


def median_ms(timings) -> tuple[float, float]:
    """(median, max - min) of a candidate's timings."""
    values = np.asarray(timings, dtype=np.float64)
    return float(np.median(values)), float(values.max() - values.min())


def summary_hash(run_dir) -> str | None:
    """Hash of a run's ``summary.json`` (None when missing): what the oracle was computed from."""
    path = Path(run_dir) / schema.SUMMARY_JSON
    if not path.is_file():
        return None
    return hashlib.blake2b(path.read_bytes(), digest_size=12).hexdigest()


def _names(text) -> list:
    return [name for name in str(text or "").split(";") if name]


def _joined(names) -> str:
    return ";".join(sorted(names))


def write_csv(path, columns, rows):
    """Rows (dicts) as a CSV through a temporary file (numbers as in the run logs)."""
    path = Path(path)
    with atomic.atomic_open(path, "w", newline="") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(columns)
        for row in rows:
            writer.writerow([run_log.format_value(row.get(key)) for key in columns])


def read_csv(path) -> list:
    with open(path, newline="", encoding="utf-8") as handle:
        return list(csv.DictReader(handle))


@dataclass
class OracleResults:
    """An oracle folder read back for the report."""

    folder: Path
    info: dict
    regret_rows: list
    candidate_rows: list

    def runs(self) -> dict:
        """{run label: {'mean_regret', 'frames', 'mean_heuristic_flip', 'mean_oracle_flip'}}."""
        return self.info.get("runs", {})

    def rows_of(self, run_label) -> list:
        return [row for row in self.regret_rows if row["run"] == run_label]

    def is_current_for(self, run_label, run_dir) -> bool:
        entry = self.runs().get(run_label)
        return entry is not None and entry.get("summary_hash") == summary_hash(run_dir)

    def is_shared_from(self, raster_dir) -> bool:
        """Whether the shared times came from the raster run ``raster_dir`` as it is now."""
        raster_dir = Path(raster_dir)
        return self.info.get("shared_from") == raster_dir.name and \
            self.info.get("shared_summary_hash") == summary_hash(raster_dir)


def read_results(folder) -> OracleResults | None:
    """The oracle folder's contents, or None when it has not been (completely) written."""
    folder = Path(folder)
    info_path = folder / ORACLE_JSON
    if not info_path.is_file():
        return None
    info = json.loads(info_path.read_text(encoding="utf-8"))
    regret_rows = []
    for row in read_csv(folder / REGRET_CSV):
        parsed = dict(row)
        for key in ("frame",):
            parsed[key] = int(row[key])
        # Re-choices of the oracle's subset held to its time (``oracle_fit``); 0 in older folders.
        parsed["oracle_refits"] = int(row["oracle_refits"]) if row.get("oracle_refits") not in (None, "") else 0
        for key in REGRET_FLOATS:
            parsed[key] = float(row[key]) if row.get(key, "") != "" else None
        for key in ("heuristic", "oracle", "oracle_only", "heuristic_only"):
            parsed[key] = _names(row[key])
        regret_rows.append(parsed)
    candidate_rows = read_csv(folder / CANDIDATES_CSV)
    return OracleResults(folder=folder, info=info, regret_rows=regret_rows, candidate_rows=candidate_rows)


def regret_row(run_label, frame, budget_ms, shared, time_left_ms, heuristic_set, heuristic_flip, oracle_set,
               oracle_flip, candidates: FrameCandidates, oracle_trace_ms=None, oracle_refits=0) -> dict:
    """One row of ``regret.csv``: a run's frame against its budget's oracle."""
    oracle_cost, oracle_benefit = candidates.totals(oracle_set)
    heuristic_cost, heuristic_benefit = candidates.totals(heuristic_set)
    return {"run": run_label, "frame": frame, "budget_ms": budget_ms, "shared_ms": shared,
            "capacity_ms": nominal_time_left(budget_ms, shared), "time_left_ms": time_left_ms,
            "raster_flip": candidates.flip_raster, "heuristic_flip": heuristic_flip,
            "oracle_flip": oracle_flip, "regret": heuristic_flip - oracle_flip,
            "heuristic": _joined(heuristic_set), "oracle": _joined(oracle_set),
            "oracle_only": _joined(set(oracle_set) - set(heuristic_set)),
            "heuristic_only": _joined(set(heuristic_set) - set(oracle_set)),
            "oracle_cost_ms": oracle_cost, "oracle_trace_ms": oracle_trace_ms, "heuristic_cost_ms": heuristic_cost,
            "oracle_benefit": oracle_benefit, "heuristic_benefit": heuristic_benefit, "oracle_refits": oracle_refits}


def write_results(folder, every, frames, candidates, regret_rows, run_dirs, note="", capped=None, shared_dir=None,
                  clock=None):
    """Write the oracle folder's three files (``oracle.json`` last: it marks completion).
    ``shared_dir``: the raster run the shared times came from (None: the oracle's own frames with
    nothing traced), named in ``shared_from`` with its summary's hash; ``clock``: how much slower the
    oracle ran than the runs (``oracle_fit.Clock.summary``: its timings were divided by it)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    write_csv(folder / CANDIDATES_CSV, CANDIDATE_COLUMNS, [
        {"frame": item.frame, "element": name, "area_px": int(item.area_px[index]) if len(item.area_px) else None,
         "cost_ms": float(item.cost_ms[index]),
         "cost_spread_ms": float(item.cost_spread_ms[index]) if len(item.cost_spread_ms) else None,
         "overhead_ms": item.overhead_ms,
         "flip_alone": float(item.flip_alone[index]) if len(item.flip_alone) else None,
         "flip_raster": item.flip_raster, "benefit": float(item.benefit[index])}
        for item in candidates for index, name in enumerate(item.names)])
    write_csv(folder / REGRET_CSV, REGRET_COLUMNS, regret_rows)
    runs = {}
    for label, run_dir in run_dirs.items():
        rows = [row for row in regret_rows if row["run"] == label]
        runs[label] = {
            "summary_hash": summary_hash(run_dir), "frames": len(rows),
            "mean_regret": float(np.mean([row["regret"] for row in rows])) if rows else None,
            "mean_heuristic_flip": float(np.mean([row["heuristic_flip"] for row in rows])) if rows else None,
            "mean_oracle_flip": float(np.mean([row["oracle_flip"] for row in rows])) if rows else None,
            "frames_oracle_differs": sum(1 for row in rows if row["oracle"] != row["heuristic"]),
            "budget_ms": rows[0]["budget_ms"] if rows else None,
        }
    info = run_log.json_ready({
        "every": every, "frames": list(frames), "runs": runs, "capped": capped or {}, "timings": TIMINGS,
        "shared_from": Path(shared_dir).name if shared_dir is not None else None,
        "shared_summary_hash": summary_hash(shared_dir) if shared_dir is not None else None,
        **(clock or {"clock_ratio": None}),
        "min_benefit": MIN_BENEFIT, "note": note or
        "computed after the runs, outside every timed region: each candidate traced alone against the "
        f"reference (cost: the median of {TIMINGS} timings), one oracle per budget: an exact knapsack on measured "
        "benefit and cost within the budget's nominal time for tracing (budget - the raster run's raster, select "
        "and composite ms on that frame; shared_from names that run: in a lockstep sweep the raster run rendered "
        "with the hybrid runs), its timings divided by clock_ratio (the runs' clock), its subset rendered and "
        "measured, chosen again when its trace overran that time; unweighted by K"})
    atomic.write_text(folder / ORACLE_JSON, json.dumps(info, indent=2, allow_nan=False) + "\n")
    return info
