"""The oracle's renders: sampled frames re-rendered with chosen subsets traced.

See ``phrt_addon/report/oracle.py`` for what is measured and decided.  Everything
here runs after the runs it judges, outside their timed regions: a
:class:`ForcedRenderer` renders a frame of the path through the real engine
(``bpy.ops.render.render``) with ``FrameRenderer.forced_selection`` set, so the
chosen elements are traced instead of the heuristic's.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

from ...phrt_addon.report import metrics, oracle, oracle_fit
from ...phrt_addon.runs import run_files, steady
from .. import extract, final
from . import item_measure


@dataclass
class RasterFrame:
    """A sampled frame with nothing traced, measured against the runs (``ForcedRenderer.raster_frame``)."""

    image: np.ndarray
    stats: dict
    selection: object
    ratio: float  # the clock ratio its timings are divided by (``oracle_fit.Clock``)
    flip: float  # its LDR-FLIP against the reference
    shared_ms: float  # what every variant spends on the frame whatever it selects, on the runs' clock


class ForcedRenderer:
    """Renders frames of ``camera`` in HYBRID mode with a given set of elements traced.

    ``with ForcedRenderer(scene, camera, resolution) as renderer:``
    ``image, stats, selection = renderer.render(frame, names)``; ``image`` is linear
    RGB, top row first (like :func:`metrics.read_image`)."""

    def __init__(self, scene, camera, resolution=None):
        self.scene, self.camera, self.resolution = scene, camera, resolution
        self.state = None
        self.warmed = False

    def __enter__(self):
        scene, render = self.scene, self.scene.render
        self._saved = {"camera": scene.camera, "frame": scene.frame_current, "engine": render.engine,
                       "res": (render.resolution_x, render.resolution_y, render.resolution_percentage)}
        scene.camera = self.camera
        render.engine = "PHRT"
        if self.resolution is not None:
            render.resolution_x, render.resolution_y = self.resolution
            render.resolution_percentage = 100
        settings = extract.read_settings(scene)
        settings.mode = "HYBRID"
        settings.budget_at = None
        self.state = final.ReplayState(settings_override=settings, camera=self.camera).__enter__()
        return self

    def __exit__(self, *exc):
        self.state.__exit__(None, None, None)
        scene, render, saved = self.scene, self.scene.render, self._saved
        scene.camera = saved["camera"]
        scene.frame_set(saved["frame"])
        render.engine = saved["engine"]
        render.resolution_x, render.resolution_y, render.resolution_percentage = saved["res"]
        return False

    def raster_frame(self, frame, reference, clock, gbuffer_of, shared_of) -> RasterFrame:
        """``frame`` with nothing traced, its LDR-FLIP against ``reference``, and the machine's speed
        now against the runs' on it (its G-buffer pass timed ``oracle.TIMINGS`` times against the
        runs' raster run's ``gbuffer_of`` {frame: ms}, observed by ``clock``).  Its shared time is
        ``shared_of`` {frame: ms} (the raster run's), else its own raster and composite on the runs'
        clock.  The first call warms up (shaders, shadow maps and Embree scenes built, not timed)."""
        if not self.warmed:
            self.warmed = True
            self.render(frame, ())
            _, _, warm = self.render(frame, ())
            self.render(frame, competing_candidates(warm))
        image, stats, selection = self.render(frame, ())
        gbuffer = [stats.get("gbuffer_ms")] + [self.render(frame, ())[1].get("gbuffer_ms")
                                               for _ in range(oracle.TIMINGS - 1)]
        ratio = clock.observe(gbuffer, gbuffer_of.get(frame))
        shared = shared_of.get(frame)
        if shared is None:  # no raster run's frame: the oracle's own, on the runs' clock
            shared = (float(stats["raster_ms"]) + float(stats.get("select_ms") or 0.0)
                      + float(stats.get("composite_ms") or 0.0)) / ratio
        return RasterFrame(image=image, stats=stats, selection=selection, ratio=ratio,
                           flip=metrics.flip(reference, image), shared_ms=shared)

    def render(self, frame, names, rates=None):
        """``rates``: per effect name the rate (``trace.rates.RATES``) every traced element's effect
        is traced at (None: full)."""
        if self.scene.frame_current != frame:
            self.scene.frame_set(frame)
        self.state.renderer.forced_selection = frozenset(names)
        self.state.renderer.forced_rates = dict(rates) if rates else None
        bpy.ops.render.render(write_still=False)
        result = self.state.last_result
        self.state.last_result = None
        if result is None:
            raise RuntimeError(f"frame {frame} was stopped while rendering")
        self.last_passes = result.passes
        image = np.ascontiguousarray(result.passes.combined[::-1, :, :3], dtype=np.float32)
        return image, result.stats, result.selection


def _selection_by_frame(run_dir):
    chosen = {}
    for row in run_files.read_selection(run_dir):
        if row["selected"]:
            chosen.setdefault(row["frame"], set()).add(str(row["element"]))
    return chosen


def _budget_groups(runs):
    """{budget ms: [labels]}: the hybrid runs judged by one oracle (their budget, rounded to 0.1 ms)."""
    groups = {}
    for label, run in runs.items():
        budget = run["budget_ms"]
        if budget is not None:
            groups.setdefault(round(float(budget), 1), []).append(label)
    return groups


def run_oracle(scene, camera, reference_dir, hybrid_dirs, out_dir, *, raster_dir=None, every=oracle.DEFAULT_EVERY,
               resolution=None, on_progress=None):
    """Measure candidates on every ``every``-th frame of the reference run, choose one oracle subset
    per budget of the hybrid runs (``{label: run dir}``) within that budget's nominal time for
    tracing, render it, and write each run's regret to the oracle folder ``out_dir``.  The shared
    part of a frame's time comes from the raster run ``raster_dir`` (else from the oracle's own
    frame with nothing traced).  Returns the folder's info."""
    reference_dir = Path(reference_dir)
    reference_frames = [row["frame"] for row in run_files.read_frames(reference_dir)]
    frames = oracle.sampled_frames(reference_frames, every)
    raster_rows = run_files.read_frames(raster_dir) if raster_dir is not None else []
    shared_of = oracle.shared_ms(raster_rows)
    # The raster run's G-buffer per frame, its first frame (one-time work) left out, as speed_against does.
    gbuffer_of = {row["frame"]: row.get("gbuffer_ms") for row in steady.steady_rows(raster_rows)}
    runs = {}
    for label, run_dir in hybrid_dirs.items():
        summary = run_files.read_summary(run_dir)
        runs[label] = {"dir": Path(run_dir), "frames": {row["frame"]: row for row in run_files.read_frames(run_dir)},
                       "selected": _selection_by_frame(run_dir), "budget_ms": summary.get("budget_ms")}
    budgets = _budget_groups(runs)
    measured, regret_rows, capped = [], [], {}
    clock = oracle_fit.Clock()
    with ForcedRenderer(scene, camera, resolution) as renderer:
        for count, frame in enumerate(frames):
            reference_path = run_files.frame_image_path(reference_dir, frame)
            if reference_path is None:
                continue
            reference = metrics.read_image(reference_path)
            # The frame's timings are divided by the clock ratio of the last few frames (``oracle_fit.Clock``).
            base = renderer.raster_frame(frame, reference, clock, gbuffer_of, shared_of)
            selection, ratio, flip_raster, shared = base.selection, base.ratio, base.flip, base.shared_ms
            competing = competing_candidates(selection)
            names, cut = oracle.cap_candidates(competing, _relevance(selection, competing), seed=frame)
            if cut:
                capped[str(frame)] = [len(names), len(competing)]
            cost, spread, alone, area = [], [], [], []
            rendered = {frozenset(): (0.0, flip_raster)}  # subset -> (its trace ms on the runs' clock, its LDR-FLIP)
            for name in names:  # the advisor's items are measured by the same function
                traced = item_measure.measure_subset(renderer, frame, (name,), reference)
                rendered[frozenset((name,))] = (traced.trace_ms / ratio, traced.flip)
                cost.append(traced.trace_ms / ratio)
                spread.append(traced.spread_ms / ratio)
                alone.append(traced.flip)
                area.append(int(selection.elements.area_px[selection.names.index(name)]))
            alone = np.array(alone, dtype=np.float64)
            cost = np.array(cost, dtype=np.float64)
            overhead = 0.0
            if len(names) > 1:  # all together: the trace stage's fixed part, paid once per frame
                together = item_measure.measure_subset(renderer, frame, names, reference)
                rendered[frozenset(names)] = (together.trace_ms / ratio, together.flip)
                overhead = oracle.trace_overhead_ms(cost, together.trace_ms / ratio)
            candidates = oracle.FrameCandidates(frame=frame, names=names, cost_ms=cost - overhead,
                                                benefit=flip_raster - alone, flip_raster=flip_raster,
                                                flip_alone=alone, area_px=np.array(area), overhead_ms=overhead,
                                                cost_spread_ms=np.array(spread, dtype=np.float64))
            measured.append(candidates)

            def measure(subset):  # rendered and measured even when a run chose the same
                traced = item_measure.measure_subset(renderer, frame, tuple(sorted(subset)), reference)
                return traced.trace_ms / ratio, traced.flip

            for labels in budgets.values():
                # The group's key is rounded (to 0.1 ms): the oracle gets its runs' smallest exact budget,
                # never more time than a run it judges had.
                exact_budget = min(float(runs[label]["budget_ms"]) for label in labels)
                oracle_set, refits = oracle_fit.feasible_choice(
                    candidates, oracle.nominal_time_left(exact_budget, shared), exact_budget, measure, rendered)
                for label in labels:
                    run = runs[label]
                    row = run["frames"].get(frame)
                    run_image = run_files.frame_image_path(run["dir"], frame)
                    if row is None or run_image is None:
                        continue
                    heuristic_set = frozenset(run["selected"].get(frame, set()))
                    heuristic_flip = metrics.flip(reference, metrics.read_image(run_image))
                    regret_rows.append(oracle.regret_row(
                        label, frame, run["budget_ms"], shared, row.get("time_left_ms"), heuristic_set,
                        heuristic_flip, oracle_set, rendered[oracle_set][1], candidates,
                        oracle_trace_ms=rendered[oracle_set][0], oracle_refits=refits))
            if on_progress is not None:
                on_progress(count + 1, len(frames))
    return oracle.write_results(out_dir, every, frames, measured, regret_rows,
                                {label: run["dir"] for label, run in runs.items()}, capped=capped,
                                shared_dir=raster_dir, clock=clock.summary())


def _relevance(selection, names) -> list:
    """The selection's own estimate (relevance R) of each of ``names``."""
    index = {name: position for position, name in enumerate(selection.names)}
    relevance = selection.terms.relevance
    return [float(relevance[index[name]]) for name in names]


def competing_candidates(selection) -> list:
    """Names of the frame's competing candidates (visible, tagged, within the area limit)."""
    terms = selection.terms
    mask = terms.candidate & terms.visible & terms.within_area
    return [name for name, keep in zip(selection.names, mask.tolist()) if keep]
