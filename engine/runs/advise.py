"""The tagging advisor's renders: ``phrt advise`` and the N panel's Advisor (docs/advice.md).

:func:`advice_steps` is a generator (one render or so per step, for the modal operator's progress
and cancel); :func:`run_advice` runs it to the end.  In order, under ``OUT/runs/``:

1. a RASTER replay of the frames (what every selection pays per frame: raster + select + composite ms,
   and which untagged objects are visible how much);
2. RAYTRACE replays of the judged frames (every ``every``-th): the designer's tags (the ray traced
   frame time), then with the untagged objects judged as temporary candidates, with images: the
   reference (RAYTRACE traces candidates; an untagged object's traced look is judged against its
   own ray traced look);
3. the budgets asked (fractions of the way from raster to ray traced frame time, from 1 and 2);
4. a HYBRID replay at each budget with each selection the scene offers (``PAPER``, and ``BENEFIT``
   where it exists): how often each traced each item;
5. on each judged frame, every item (each tagged effect of each competing element, and each
   effect of the most promising untagged objects made temporary candidates) traced alone through
   the oracle's own measurement (``item_measure.measure_subset``: median of 3 timings, LDR-FLIP
   against the reference), then all together for the trace stage's fixed part; the books and the
   advice are the core's (``phrt_addon/advise``).
"""
from __future__ import annotations

import time
from pathlib import Path

import bpy
import numpy as np

from ...phrt_addon.report import metrics, oracle
from ...phrt_addon.runs import run_files
from ...phrt_addon.select import mode_budgets
from ...phrt_addon.advise import charts, export, files, items, recommend
from ...phrt_addon.schema import EFFECTS
from .. import extract
from . import item_measure, replay
from . import oracle as oracle_engine

DEFAULT_BUDGET_AT = (0.25, 0.5, 0.75)
DEFAULT_EVERY = 4
RUNS_DIR = "runs"
TAGS_JSON = "tags.json"


class AdviceCancelled(Exception):
    """The designer stopped the advice (nothing is written)."""


def selections_offered(scene) -> list:
    """``PAPER``, and ``BENEFIT`` when this build's ``Scene.phrt.selection`` offers it."""
    settings = scene.phrt
    if not hasattr(settings, "selection"):
        return ["PAPER"]
    offered = [item.identifier for item in settings.bl_rna.properties["selection"].enum_items]
    return [name for name in ("PAPER", "BENEFIT") if name in offered]


def scene_selection(scene) -> str:
    return str(getattr(scene.phrt, "selection", "PAPER")).upper()


def _elements(scene, camera):
    """The scene's elements with their settings and the material under most of their triangles."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    snapshot = extract.extract(depsgraph, camera_override=camera)
    votes = {}
    for mesh in snapshot.meshes:
        for element, material in zip(mesh.tri_element.tolist(), mesh.tri_material.tolist()):
            if element >= 0:
                votes.setdefault(element, {}).setdefault(material, 0)
                votes[element][material] += 1
    result = {}
    for index, element in enumerate(snapshot.elements):
        counts = votes.get(index, {0: 1})
        material = snapshot.materials[max(counts, key=counts.get)]
        result[element.name] = (element, material)
    return result


def _replay_steps(scene, camera, frames, mode, run_dir, *, images, resolution, label, budget_ms=None,
                  overrides=None, frame_list=None):
    run = replay.ReplayRun(scene, camera, frames, mode, run_dir, images=images, resolution=resolution,
                               scene_label=label, budget_ms=budget_ms, overrides=overrides, frame_list=frame_list)
    try:
        while run.remaining:
            run.step()
            yield run.done, run.total
    except BaseException:
        run.finish(cancelled=True)
        raise
    run.finish()


def _prospects(rows, elements, frame_px, cap):
    """The untagged object elements worth judging, from the raster run's selection rows."""
    seen = {}
    frames = {row["frame"] for row in rows}
    for row in rows:
        name = str(row["element"])
        if row.get("visible") and name in elements and not elements[name][0].is_candidate:
            seen.setdefault(name, []).append(float(row["A"] or 0.0) * frame_px)
    found = []
    for name, pixels in seen.items():
        element, material = elements[name]
        if element.material_name is not None:
            continue  # a material's faces: tagged through the material, never a prospect here
        effects = items.prospect_effects(material.metallic, material.roughness, material.transmission,
                                         material.alpha, material.casts_shadow, float(np.mean(pixels)) / frame_px)
        found.append(items.Prospect(name, effects, float(np.mean(pixels)), len(pixels) / max(len(frames), 1)))
    return items.choose_prospects(found, cap)


def advice_steps(scene, camera, frame_range, out_dir, *, budget_at=DEFAULT_BUDGET_AT, resolution=None,
                 every=DEFAULT_EVERY, prospects_cap=items.DEFAULT_PROSPECTS, scene_label=None, should_stop=None,
                 budget_ms=()):
    """Yield ``(done, total, what)`` while advising; the last value is ``("done", files)``.  ``budget_ms``
    adds budgets in milliseconds (labelled by the fraction of the way they are at)."""
    begin = time.perf_counter()
    out = Path(out_dir)
    work = out / RUNS_DIR
    label = scene_label or scene.name
    start, end = frame_range
    all_frames = list(range(start, end + 1))
    judged = oracle.sampled_frames(all_frames, every)
    offered = selections_offered(scene)
    fractions = sorted({float(fraction) for fraction in budget_at})
    total = len(all_frames) * (1 + (len(fractions) + len(budget_ms)) * len(offered)) + len(judged) * 2 + len(judged) + 1
    done = 0

    def tick(what):
        nonlocal done
        done += 1
        if should_stop is not None and should_stop():
            raise AdviceCancelled("advice stopped")
        return done, total, what

    for _ in _replay_steps(scene, camera, frame_range, "RASTER", work / "raster", images="none",
                           resolution=resolution, label=label):
        yield tick("raster replay")
    elements = _elements(scene, camera)
    width, height = run_files.read_summary(work / "raster")["resolution"]
    chosen_prospects, left_out = _prospects(run_files.read_selection(work / "raster"), elements, width * height,
                                            prospects_cap)
    prospect_effects = {prospect.element: prospect.effects for prospect in chosen_prospects}
    # The designer's ray traced frame time (for the budgets), then the reference: the same frames
    # ray traced with the untagged objects judged as temporary candidates (RAYTRACE traces candidates).
    for _ in _replay_steps(scene, camera, frame_range, "RAYTRACE", work / "raytrace", images="none",
                           resolution=resolution, label=label, frame_list=judged):
        yield tick("ray traced frame time")
    with item_measure.ItemScope(prospect_effects):
        for _ in _replay_steps(scene, camera, frame_range, "RAYTRACE", work / "reference", images="exr",
                               resolution=resolution, label=label, frame_list=judged):
            yield tick("ray traced reference")
    resolved = {fraction: mode_budgets.from_runs(fraction, work / "raster", work / "raytrace") for fraction in fractions}
    budgets_ms = {fraction: resolved[fraction].budget_ms for fraction in fractions}
    ends = mode_budgets.from_runs(0.0, work / "raster", work / "raytrace")
    for milliseconds in budget_ms:
        span = ends.raytrace_ms - ends.raster_ms
        budgets_ms[(float(milliseconds) - ends.raster_ms) / span if span > 0 else 1.0] = float(milliseconds)
    fractions = sorted(budgets_ms)
    shared = oracle.shared_ms(run_files.read_frames(work / "raster"))
    effects_of = {name: tuple(effect for effect in EFFECTS if getattr(element, effect))
                  for name, (element, _) in elements.items() if element.is_candidate}
    effects_of.update(prospect_effects)
    tagged = {items.item_key(name, effect): name not in prospect_effects
              for name, effects in effects_of.items() for effect in effects}
    keys_of_element = {name: [items.item_key(name, effect) for effect in effects]
                       for name, effects in effects_of.items() if name not in prospect_effects}
    selections = {}
    for name in offered:
        for fraction in fractions:
            run_dir = work / f"hybrid-{name.lower()}-{fraction:g}"
            overrides = {"selection": name} if "BENEFIT" in offered else None
            for _ in _replay_steps(scene, camera, frame_range, "HYBRID", run_dir, images="none",
                                   resolution=resolution, label=label, budget_ms=budgets_ms[fraction],
                                   overrides=overrides):
                yield tick(f"{name} replay at {fraction:g}")
            selections.setdefault(name, {})[fraction] = items.selection_shares(run_files.read_selection(run_dir),
                                                                               keys_of_element)
    measured, best = [], {}
    maps_dir = out / files.MAPS_DIR
    maps_dir.mkdir(parents=True, exist_ok=True)
    with oracle_engine.ForcedRenderer(scene, camera, resolution) as renderer, \
            item_measure.ItemScope(prospect_effects) as scope:
        for count, frame in enumerate(judged):
            reference_path = run_files.frame_image_path(work / "reference", frame)
            if reference_path is None:
                continue
            reference = metrics.read_image(reference_path)
            if count == 0:  # warm-up: shaders, shadow maps and Embree scenes are built once, not timed here
                renderer.render(frame, ())
                _, _, warm = renderer.render(frame, ())
                scope.trace_only({})
                renderer.render(frame, oracle_engine.competing_candidates(warm))
            scope.trace_only({})
            raster = item_measure.measure_subset(renderer, frame, (), reference, timings=1, per_pixel=True)
            competing = [name for name in oracle_engine.competing_candidates(raster.selection) if name in effects_of]
            frame_items = [(name, effect) for name in competing for effect in effects_of[name]]
            keys, cost, benefit, area = [], [], [], []
            for name, effect in frame_items:
                forced = scope.trace_only({name: (effect,)})
                alone = item_measure.measure_subset(renderer, frame, forced, reference, per_pixel=True)
                key = items.item_key(name, effect)
                keys.append(key)
                cost.append(alone.trace_ms)
                benefit.append(raster.flip - alone.flip)
                area.append(int(raster.selection.elements.area_px[raster.selection.names.index(name)]))
                if benefit[-1] > best.get(key, (-np.inf, None))[0]:
                    best[key] = (benefit[-1], frame)
                    charts.write_drop_map(maps_dir / files.map_name(key), raster.flip_map - alone.flip_map)
            overhead = 0.0
            if len(frame_items) > 1:  # all together: the trace stage's fixed part, paid once per frame
                forced = scope.trace_only({name: effects_of[name] for name in competing})
                together = item_measure.measure_subset(renderer, frame, forced)
                overhead = oracle.trace_overhead_ms(cost, together.trace_ms)
            scope.trace_only({})
            measured.append(oracle.FrameCandidates(
                frame=frame, names=keys, cost_ms=np.array(cost, dtype=np.float64) - overhead,
                benefit=np.array(benefit, dtype=np.float64), flip_raster=raster.flip,
                area_px=np.array(area), overhead_ms=overhead))
            yield tick(f"judged frame {frame}")
    books = items.books(measured, tagged, budgets_ms, shared, selections, judged_frames=len(judged))
    selection = scene_selection(scene)
    advice = recommend.recommend(books, selection)
    seconds = time.perf_counter() - begin
    info = {"scene": label, "path": camera.name, "frames": [start, end], "judged_frames": len(judged),
            "every": every, "resolution": [width, height], "budgets_ms": budgets_ms, "selections": offered,
            "selection": selection, "judged": judged,
            "prospects": {"judged": sorted(prospect_effects), "cap": prospects_cap, "left_out": left_out},
            "seconds": seconds, "seconds_per_judged_frame": seconds / max(len(judged), 1),
            "maps": {key: files.map_name(key) for key in best}}
    written = files.write_advice(out, books, advice, info)
    rows = files.advice_rows(books, advice, fractions)
    settings = {name: item_measure.read_settings(owner) for name in elements
                if (owner := item_measure.owner_of(name)) is not None}
    written["tags"] = export.write_export(out / TAGS_JSON, export.export_tags(rows, settings, label, camera.name))
    yield tick("files")
    yield "done", written


def run_advice(scene, camera, frame_range, out_dir, *, on_progress=None, **options) -> dict:
    """Run :func:`advice_steps` to the end; returns the files written ({name: path})."""
    for step in advice_steps(scene, camera, frame_range, out_dir, **options):
        if step[0] == "done":
            return step[1]
        if on_progress is not None:
            on_progress(*step)
    raise RuntimeError("advice ended without its files")
