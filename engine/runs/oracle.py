"""The oracle's renders: sampled frames re-rendered with chosen subsets traced.

See ``phrt_addon/report/oracle.py`` for what is measured and decided.  Everything
here runs after the runs it judges, outside their timed regions: a
:class:`ForcedRenderer` renders a frame of the path through the real engine
(``bpy.ops.render.render``) with ``FrameRenderer.forced_selection`` set, so the
chosen elements are traced instead of the heuristic's.
"""
from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from ...phrt_addon.report import metrics, oracle
from ...phrt_addon.runs import run_files
from .. import extract, final
from . import item_measure


class ForcedRenderer:
    """Renders frames of ``camera`` in HYBRID mode with a given set of elements traced.

    ``with ForcedRenderer(scene, camera, resolution) as renderer:``
    ``image, stats, selection = renderer.render(frame, names)``; ``image`` is linear
    RGB, top row first (like :func:`metrics.read_image`)."""

    def __init__(self, scene, camera, resolution=None):
        self.scene, self.camera, self.resolution = scene, camera, resolution
        self.session = None

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
        self.session = final.ReplaySession(settings_override=settings, camera=self.camera).__enter__()
        return self

    def __exit__(self, *exc):
        self.session.__exit__(None, None, None)
        scene, render, saved = self.scene, self.scene.render, self._saved
        scene.camera = saved["camera"]
        scene.frame_set(saved["frame"])
        render.engine = saved["engine"]
        render.resolution_x, render.resolution_y, render.resolution_percentage = saved["res"]
        return False

    def render(self, frame, names):
        if self.scene.frame_current != frame:
            self.scene.frame_set(frame)
        self.session.renderer.forced_selection = frozenset(names)
        bpy.ops.render.render(write_still=False)
        result = self.session.last_result
        self.session.last_result = None
        if result is None:
            raise RuntimeError(f"frame {frame} was stopped while rendering")
        image = np.ascontiguousarray(result.passes.combined[::-1, :, :3], dtype=np.float32)
        return image, result.stats, result.selection


def _selection_by_frame(run_dir):
    chosen = {}
    for row in run_files.read_selection(run_dir):
        if row["selected"]:
            chosen.setdefault(row["frame"], set()).add(str(row["element"]))
    return chosen


def run_oracle(scene, camera, reference_dir, hybrid_dirs, out_dir, *, every=oracle.DEFAULT_EVERY,
               resolution=None, on_progress=None):
    """Measure candidates on every ``every``-th frame of the reference run and the regret of each
    hybrid run (``{label: run dir}``); write the oracle folder ``out_dir``.  Returns its info."""
    reference_dir = Path(reference_dir)
    reference_frames = [row["frame"] for row in run_files.read_frames(reference_dir)]
    frames = oracle.sampled_frames(reference_frames, every)
    runs = {label: {"dir": Path(run_dir), "frames": {row["frame"]: row for row in run_files.read_frames(run_dir)},
                    "selected": _selection_by_frame(run_dir)} for label, run_dir in hybrid_dirs.items()}
    measured, regret_rows = [], []
    with ForcedRenderer(scene, camera, resolution) as renderer:
        for count, frame in enumerate(frames):
            reference_path = run_files.frame_image_path(reference_dir, frame)
            if reference_path is None:
                continue
            reference = metrics.read_image(reference_path)
            if count == 0:  # warm-up: shaders, shadow maps and Embree scenes are built once, not timed here
                renderer.render(frame, ())
                _, _, warm = renderer.render(frame, ())
                renderer.render(frame, _competing(warm))
            raster, _, selection = renderer.render(frame, ())
            flip_raster = metrics.flip(reference, raster)
            names = _competing(selection)
            cost, alone, area = [], [], []
            images = {frozenset(): raster}
            for name in names:  # the advisor's items are measured by the same function
                traced = item_measure.measure_subset(renderer, frame, (name,), reference, timings=1)
                images[frozenset((name,))] = traced.image
                cost.append(traced.trace_ms)
                alone.append(traced.flip)
                area.append(int(selection.elements.area_px[selection.names.index(name)]))
            alone = np.array(alone, dtype=np.float64)
            cost = np.array(cost, dtype=np.float64)
            overhead = 0.0
            if len(names) > 1:  # all together: the trace stage's fixed part, paid once per frame
                image, stats, _ = renderer.render(frame, names)
                images[frozenset(names)] = image
                overhead = oracle.trace_overhead_ms(
                    cost, max(float(stats["trace_ms"]) - float(stats.get("upload_ms") or 0.0), 0.0))
            candidates = oracle.FrameCandidates(frame=frame, names=names, cost_ms=cost - overhead,
                                                benefit=flip_raster - alone, flip_raster=flip_raster,
                                                flip_alone=alone, area_px=np.array(area), overhead_ms=overhead)
            measured.append(candidates)
            errors = {frozenset(): flip_raster, **{frozenset((n,)): e for n, e in zip(names, alone.tolist())}}
            for label, run in runs.items():
                row = run["frames"].get(frame)
                run_image = run_files.frame_image_path(run["dir"], frame)
                if row is None or run_image is None:
                    continue
                heuristic_set = frozenset(run["selected"].get(frame, set()))
                heuristic_flip = metrics.flip(reference, metrics.read_image(run_image))
                time_left = float(row.get("time_left_ms") or 0.0)
                oracle_set = candidates.choose(candidates.capacity(time_left, heuristic_set))
                if oracle_set == heuristic_set:
                    oracle_flip = heuristic_flip  # the same selection renders the same image
                else:
                    if oracle_set not in errors:
                        image = images.get(oracle_set)
                        if image is None:
                            image, _, _ = renderer.render(frame, oracle_set)
                        errors[oracle_set] = metrics.flip(reference, image)
                    oracle_flip = errors[oracle_set]
                regret_rows.append(oracle.regret_row(label, frame, time_left, heuristic_set, heuristic_flip,
                                                     oracle_set, oracle_flip, candidates))
            if on_progress is not None:
                on_progress(count + 1, len(frames))
    return oracle.write_results(out_dir, every, frames, measured, regret_rows,
                                {label: run["dir"] for label, run in runs.items()})


def _competing(selection) -> list:
    """Names of the frame's competing candidates (visible, tagged, within the area limit)."""
    terms = selection.terms
    mask = terms.candidate & terms.visible & terms.within_area
    return [name for name, keep in zip(selection.names, mask.tolist()) if keep]
