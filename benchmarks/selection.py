"""Benchmark of the selection heuristic: time per frame against the number of candidates.

``run()`` prints a table for 10 ... 100,000 candidates: the median time of one
frame's selection (T from the cost model, the paper's terms, predicted ms, the
selection graph and node selection), the same with the construction of the
frame's element arrays (their validation), the ratio between successive sizes
next to the n log n ratio it should follow, and the targets (under 1 ms for 100
candidates, under 20 ms for 10,000).

The scenes are random but seeded, about a third of the candidates' predicted
cost fits in the time left (so node selection walks far down the relevance
order), half of the candidates were selected last frame, and the cost model is
warm (it has learned per-element rays, as in a running replay).
"""
from __future__ import annotations

import math
import statistics
import time

import numpy as np

from ..phrt_addon.select.benefit_selection import BenefitSelector
from ..phrt_addon.select.cost_model import EFFECTS, CostModel, FrameStats
from ..phrt_addon.select.heuristic import select
from ..phrt_addon.select.selection_terms import FrameElements, SelectionSettings

SIZES = (10, 100, 1_000, 10_000, 100_000)
TARGETS_MS = {100: 1.0, 10_000: 20.0}
FRAME_PX = 640 * 480
BUDGET_MS = 150.0


def bench_fields(n: int, seed: int = 0) -> dict:
    """The arrays of a random frame of n candidates covering ~80% of the frame."""
    rng = np.random.default_rng(seed)
    share = rng.dirichlet(np.full(n, 0.5)) if n else np.zeros(0)
    area = np.floor(share * 0.8 * FRAME_PX).astype(np.int64)
    effects = rng.random((3, n)) < 0.5
    return dict(names=[f"element{i}" for i in range(n)], area_px=area, frame_px=FRAME_PX,
                candidate=rng.random(n) < 0.9, centre_ndc=rng.uniform(-1, 1, (n, 2)),
                distance=rng.uniform(0.5, 80.0, n), priority=rng.uniform(0.5, 2.0, n), rt_cost=np.ones(n),
                shadows=effects[0], reflections=effects[1], refractions=effects[2],
                rays_per_pixel=effects.T @ np.array([2.0, 1.0, 3.0]))


def _warm_model(elements: FrameElements, settings: SelectionSettings):
    """A cost model after a few frames of the replay, and the last selection."""
    model = CostModel()
    previous = None
    for _ in range(3):
        result = select(elements, previous, settings, model)
        rays = elements.area_px * elements.rays_per_pixel * result.selected
        model.observe(FrameStats(raster_ms=40.0, select_ms=1.0, composite_ms=5.0,
                                 trace_ms=float(rays.sum()) * 2e-4,
                                 effect_rays={effect: float(rays.sum()) / 3 for effect in EFFECTS},
                                 element_rays=rays), result)
        previous = result
    # Leave about a third of the candidates' predicted time to fit.
    predicted = model.predict_element_ms(elements, np.zeros(len(elements)), settings.cost_mode)
    budget = model.non_trace_ms() + float(predicted.sum()) / 3
    return model, previous, SelectionSettings(budget_ms=budget, cost_mode=settings.cost_mode)


def time_frame(n: int, min_seconds: float = 0.2, max_repeats: int = 200, seed: int = 0) -> dict:
    """Median ms of one frame's selection for n candidates."""
    fields = bench_fields(n, seed)
    elements = FrameElements(**fields)
    model, previous, settings = _warm_model(elements, SelectionSettings(budget_ms=BUDGET_MS))
    select_ms, with_build_ms = [], []
    started = time.perf_counter()
    while len(select_ms) < 3 or (time.perf_counter() - started < min_seconds and len(select_ms) < max_repeats):
        begin = time.perf_counter()
        elements = FrameElements(**fields)
        built = time.perf_counter()
        model.time_left(settings.budget_ms)
        result = select(elements, previous, settings, model)
        done = time.perf_counter()
        select_ms.append((done - built) * 1e3)
        with_build_ms.append((done - begin) * 1e3)
    return dict(n=n, select_ms=statistics.median(select_ms), with_build_ms=statistics.median(with_build_ms),
                selected=int(result.selected.sum()), repeats=len(select_ms))


def run(out=print, sizes=SIZES) -> list[dict]:
    """Time the selection for each size and print the table; returns its rows."""
    rows = []
    out("Selection heuristic: time per frame (median), measured cost mode, warm cost model")
    out(f"{'candidates':>10} {'select ms':>10} {'+build ms':>10} {'ratio':>7} {'n log n':>8} "
        f"{'selected':>9} {'target':>16}")
    for n in sizes:
        row = time_frame(n)
        previous = rows[-1] if rows else None
        row["ratio"] = row["select_ms"] / previous["select_ms"] if previous else None
        row["n_log_n_ratio"] = (n * math.log(n)) / (previous["n"] * math.log(previous["n"])) if previous else None
        target = TARGETS_MS.get(n)
        verdict = "" if target is None else f"< {target:g} ms {'ok' if row['select_ms'] < target else 'MISSED'}"
        ratio = f"{row['ratio']:7.2f}" if previous else f"{'':>7}"
        n_log_n = f"{row['n_log_n_ratio']:8.2f}" if previous else f"{'':>8}"
        out(f"{n:>10,} {row['select_ms']:10.3f} {row['with_build_ms']:10.3f} {ratio} {n_log_n} "
            f"{row['selected']:>9,} {verdict:>16}")
        rows.append(row)
    return rows


# Each effect's fixed part in the benchmark's instances (synthetic, in the items' cost units).
BENCH_FIXED_MS = np.array([2.0, 1.0, 1.0])


def time_benefit_choice(n: int, min_seconds: float = 0.2, max_repeats: int = 200, seed: int = 0,
                        tiers: bool = False, explore: bool = True) -> dict:
    """Median ms of the BENEFIT selection's choice (values, switching, exploration, knapsack with
    each effect's fixed part paid once; ``tiers``: a rate per item) over the 3 effects of n
    candidates, a third of the items' cost fitting, half of them kept.  ``explore``: most items
    never measured, so every frame runs the exploration's second knapsack (the worst case);
    otherwise every item was measured once (a replay's usual frame: one knapsack)."""
    rng = np.random.default_rng(seed)
    names = [f"element{i}" for i in range(n)]
    eligible = rng.random((n, 3)) < 0.5
    pixels = rng.integers(1, 5000, (n, 3)).astype(float)
    priors = rng.random((n, 3)) * 0.3
    cost = rng.random((n, 3)) * 5.0
    time_left = float(cost[eligible].sum()) / 3
    selector = BenefitSelector()
    args = (names, eligible, pixels, priors, np.ones(n), cost, time_left, 0.0)
    if not explore:  # one frame with room for every item measures them all
        everything = selector.choose(*args[:6], float(cost[eligible].sum()) * 10 + 100.0, 0.0, tiers=tiers,
                                     fixed_ms=BENCH_FIXED_MS)
        selector.observe(names, everything, priors, np.where(everything.chosen, pixels * priors, 0.0), pixels)
    choice = selector.choose(*args, tiers=tiers, fixed_ms=BENCH_FIXED_MS)
    selector.observe(names, choice, priors, np.where(choice.chosen, pixels * priors, 0.0), pixels)
    selector.observe_time(1.0, 1.0)
    times = []
    started = time.perf_counter()
    while len(times) < 3 or (time.perf_counter() - started < min_seconds and len(times) < max_repeats):
        begin = time.perf_counter()
        choice = selector.choose(*args, tiers=tiers, fixed_ms=BENCH_FIXED_MS)
        times.append((time.perf_counter() - begin) * 1e3)
    return dict(n=n, items=int(eligible.sum()), choose_ms=statistics.median(times), chosen=int(choice.chosen.sum()))


def run_benefit(out=print, sizes=SIZES[:4]) -> list[dict]:
    """Time the BENEFIT choice for each size and print the table; returns its rows."""
    rows = []
    out("BENEFIT selection: choice per frame (median), 3 effects per candidate, half of them tagged;")
    out("'usual': every item measured once (one knapsack); 'exploring': most never measured (two)")
    out(f"{'candidates':>10} {'items':>7} {'usual ms':>9} {'exploring ms':>13} {'chosen':>7} {'target':>16}")
    for tiers in (False, True):
        if tiers:
            out("with quality tiers (off, quarter, half or full rate per item: the multiple-choice knapsack)")
        for n in sizes if not tiers else [size for size in sizes if size <= 1000]:
            usual = time_benefit_choice(n, tiers=tiers, explore=False)
            row = time_benefit_choice(n, tiers=tiers)
            target = TARGETS_MS.get(n)
            worst = max(usual["choose_ms"], row["choose_ms"])
            verdict = "" if target is None else f"< {target:g} ms {'ok' if worst < target else 'MISSED'}"
            out(f"{n:>10,} {row['items']:>7,} {usual['choose_ms']:9.3f} {row['choose_ms']:13.3f} "
                f"{row['chosen']:>7,} {verdict:>16}")
            rows.append(dict(row, tiers=tiers, usual_ms=usual["choose_ms"]))
    return rows


if __name__ == "__main__":
    run()
    run_benefit()
