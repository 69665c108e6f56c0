"""One PHRT frame after the G-buffer: selection, ray tracing, then lighting and composite.

``FrameRenderer`` lives for a whole replay (one per engine instance or CLI run):
it keeps the Embree scenes, the cost model and last frame's selection (the
paper's S).  ``render()`` takes a snapshot and a ``RasterFrame`` whose G-buffer
is already drawn, and returns every pass plus the statistics and selection rows
of the logs.

A ``RasterFrame`` is the raster half: ``engine/gpu/frame.GPUFrame`` (GLSL on Blender's
``gpu`` module) in the engine, ``raster.reference_raster.ReferenceRaster`` (numpy, the same
equations) in core tests.  It provides the front element ids, view depth and
normal (read back after the G-buffer), the full layers on request (only when
rays will be traced), and ``shade(traced)``: deferred lighting and composite,
with the tracer's results where it replaced the raster ones.

Stages (the columns of frames.csv, docs/formats.md):
- raster_ms     G-buffer, its read-back, shadow maps (re-rendered only after a change),
                and in HYBRID/RAYTRACE the layers read back for rays;
- select_ms     element statistics from the element-id image and the heuristic;
- trace_ms      Embree upload of changed geometry, shadow / reflection / refraction rays,
                shading of the ray hits, and the upload of their results to the GPU;
- composite_ms  the deferred lighting passes, composite, read-back of the image and its passes.

Pay only for what is used: RASTER never touches the tracer (``embreex`` is not
even imported) nor reads the layers back, no lights means no shadow work, and no
candidate in view means no Embree work at all (the first frame with one builds the Embree
scenes, whether it traces or not).
"""
from __future__ import annotations

import time
from dataclasses import replace as dataclass_replace

import numpy as np

from .select import benefit, benefit_selection, heuristic, item_benefit, item_costs, selection_terms
from .scene import shading
from .select.cost_model import CostModel, FrameStats
from .frame_types import FramePasses, FrameResult, LayerPixels, RasterFrame
from .raster.gbuffer import PixelGrid, element_pixel_stats, front_points
from .finite import finite
from .problems import ProblemLog
from .scene.snapshot import SceneSnapshot
from .trace.element_bounds import ElementBounds
from .trace.shadow_region import ShadowRegionIndex
from .trace.stage import TraceStage
from .trace.rates import forced_rates
from .select.item_rays import effect_rays_per_pixel, expected_rays, flags_array
from .trace.trace_result import TraceResult, traced_effects
from .trace.trace_rect import ShadowHulls, trace_rect


# Pixel sub-sampling step used to estimate each element's shadow footprint for the cost model.
FOOTPRINT_STEP = 8


def _timer():
    return time.perf_counter()


def _ms(start):
    return (time.perf_counter() - start) * 1000.0


class FrameRenderer:
    """Renders the frames of one replay, carrying state from frame to frame."""

    def __init__(self, threads: int | None = None):
        self.threads = threads
        self.cost_model = None
        self.previous_selection = {}
        self.trace_stage = TraceStage(threads)
        self.frames_rendered = self.traced_frames = 0
        self.element_bounds = ElementBounds()
        self.pixel_grid = PixelGrid()  # the pixel coordinates of element_pixel_stats, kept per size
        self.benefit_model = benefit.BenefitModel()  # the error-aware relevance's per-element estimates
        self.benefit_selector = benefit_selection.BenefitSelector()  # BENEFIT's per-item estimates, margin
        self.item_costs = item_costs.ItemCosts()
        # Names to trace instead of the heuristic's choice (the oracle, outside timed runs), or None;
        # with it, per effect name the rate every element's effect is traced at (tools/rate_flip.py).
        self.forced_selection = None
        self.crop_readback, self.shadow_hulls = True, ShadowHulls()  # read back what traced effects change
        self.forced_rates = None
        self.problems = ProblemLog()  # what this replay's snapshots skipped or approximated (engine/final.py)

    @property
    def trace_scene(self):
        """The replay's Embree scenes (None until a frame traced)."""
        return self.trace_stage.trace_scene

    def close(self):
        self.trace_stage.close()

    # ------------------------------------------------------------------
    def render(self, snapshot: SceneSnapshot, raster: RasterFrame) -> FrameResult:
        settings = snapshot.settings
        mode = settings.mode.upper()
        materials = getattr(raster, "materials", None)  # the raster half's table of this snapshot, if any
        if not isinstance(materials, shading.MaterialTable):
            materials = shading.MaterialTable(snapshot.materials)
        if self.cost_model is None:
            self.cost_model = CostModel()
        n_elements = len(snapshot.elements)
        candidate = np.array([e.is_candidate for e in snapshot.elements], bool)

        # -- element statistics; the layers are read back only if rays may be traced ----
        start = _timer()
        front = raster.front_element
        area_px, centre_ndc, distance = element_pixel_stats(front, n_elements, raster.view_depth, self.pixel_grid)
        select_ms = _ms(start)
        layers = None
        readback_ms = 0.0
        may_trace = mode != "RASTER" and bool(np.any(candidate & (area_px > 0)))
        use_benefit = may_trace and mode == "HYBRID" and str(settings.selection).upper() == "BENEFIT"
        learn_benefit = may_trace and mode == "HYBRID" and str(settings.relevance).upper() == "ERROR" \
            and not use_benefit

        def read_layers(elements=None, rect=None):  # elements: only their pixels; rect: only that read back
            gbuffer = raster.gbuffer(rect)
            return {name: LayerPixels(getattr(gbuffer, name), gbuffer.origin, snapshot.camera, materials, elements, rect)
                    for name in ("opaque", "transparent")}

        # The benefit priors read the materials under each element's pixels: under BENEFIT only when an
        # item visible now has no prior yet, or the cached ones are PRIOR_EVERY frames old (a frame
        # that traces reads the layers anyway, after the selection).
        need_priors = use_benefit and self.benefit_selector.needs_priors(
            [e.name for e in snapshot.elements], candidate & (area_px > 0)) and not self._no_time_to_trace(
            settings, raster.raster_ms - raster.setup_ms)
        if learn_benefit or need_priors:
            start = _timer()
            layers = read_layers()
            readback_ms = _ms(start)
        raster_ms = raster.raster_ms + readback_ms

        # -- selection --------------------------------------------------------
        start = _timer()
        shadow_lights = [light for light in snapshot.lights if light.cast_shadows]
        element_bounds = self.element_bounds(snapshot)
        footprint = self._shadow_footprints(raster, snapshot, element_bounds, area_px) \
            if shadow_lights and may_trace else np.zeros(n_elements)
        flags = {effect: np.array([getattr(e, effect) for e in snapshot.elements], bool)
                 for effect in ("shadows", "reflections", "refractions")}
        effect_rays = effect_rays_per_pixel(snapshot, area_px, footprint)
        expected_benefit = self.benefit_model.benefit(
            [e.name for e in snapshot.elements],
            benefit.prior_per_pixel(layers, n_elements, flags["reflections"], flags["refractions"],
                                    flags["shadows"], materials)) if learn_benefit else None
        frame_elements = selection_terms.FrameElements(
            names=[e.name for e in snapshot.elements], candidate=candidate,
            area_px=area_px, centre_ndc=centre_ndc, distance=distance,
            priority=np.array([e.priority for e in snapshot.elements], float),
            rt_cost=np.array([e.rt_cost for e in snapshot.elements], float),
            shadows=flags["shadows"], reflections=flags["reflections"], refractions=flags["refractions"],
            rays_per_pixel=np.sum(effect_rays * flags_array(flags), axis=1),
            frame_px=raster.width * raster.height,
            near_clip=snapshot.camera.clip_start,
            benefit=expected_benefit,
        )
        selection = heuristic.select(
            frame_elements, self.previous_selection,
            selection_terms.SelectionSettings(budget_ms=settings.budget_ms, selection_weight=settings.selection_weight,
                                        max_area_fraction=settings.max_area_fraction, mode=mode,
                                        cost_mode=settings.cost_mode, relevance=settings.relevance,
                                        order=settings.selection_order, budget_at=settings.budget_at),
            self.cost_model, frame=snapshot.frame,
            # The time left is measured after this frame's raster half, not predicted for it.  The
            # BENEFIT priors' read-back of the layers is the one the trace stage would do (its fixed
            # overhead, charged against T, holds it): not taken from T twice.  It was, every
            # PRIOR_EVERY frames, and items that just fit were dropped for that frame and taken
            # back the next (atrium path2 at 0.5: flips 8 frames apart).
            raster_ms=max(raster_ms - raster.setup_ms - (readback_ms if need_priors else 0.0), 0.0),
            choose=not (use_benefit and self.forced_selection is None))  # BENEFIT chooses its items itself
        choice = item_priors = None
        pixels = item_benefit.item_pixels(area_px, footprint)  # what each (element, effect) item changes
        if use_benefit and self.forced_selection is None:
            item_priors = self.benefit_selector.priors(
                frame_elements.names, item_benefit.priors(layers, n_elements, flags, materials) if need_priors else None)
            choice, selection = self._choose_items(selection, frame_elements, item_priors, pixels, effect_rays,
                                                   tiers=bool(getattr(settings, "quality_tiers", False)))
        if self.forced_selection is not None:
            selection = heuristic.force_selection(selection, self.forced_selection)
        selected = np.asarray(selection.selected, bool)
        select_ms += _ms(start)

        # -- ray tracing ------------------------------------------------------
        start = _timer()
        # The replay's first frame that may trace builds what a later frame would stall on at its
        # first trace (the Embree scenes, every mesh's bounds): one-time work, in its set-up.
        prepare_ms = self._prepare_tracing(snapshot, materials) if may_trace and self.trace_scene is None else 0.0
        traced_frame = TraceResult(traced=None, element_rays=np.zeros(n_elements))
        if np.any(selected) and may_trace:
            if layers is None:  # only a frame that traces reads the layers back (a trace cost)
                begin, wanted = _timer(), traced_effects(snapshot.elements, selected, selection.effects)
                layers = read_layers(self.ray_pixels(snapshot, selected, selection.effects), trace_rect(
                    snapshot, wanted, element_bounds, self.element_bounds.scene_bounds(snapshot) if np.any(
                        wanted["shadows"]) and shadow_lights else None, raster.width, raster.height,
                    self.shadow_hulls) if self.crop_readback else None)
                readback_ms = _ms(begin)
            traced_frame = self.trace_stage.run(snapshot, layers, materials, selected, element_bounds,
                                                effects=selection.effects,
                                                rates=choice.rates if choice is not None else
                                                self._forced_rates(frame_elements.names))
        traced, counters, element_rays = traced_frame.traced, traced_frame.counters, traced_frame.element_rays
        upload_ms = counters.upload_ms + prepare_ms  # Embree builds: one-time work
        trace_ms = _ms(start)
        # A replay's first trace (tracer imports, first buffers) teaches the overhead alone (revised if it prices tracing out).
        warm = traced is not None and self.traced_frames > 0
        self.traced_frames += traced is not None

        # -- lighting and composite (GPU) -----------------------------------------
        start = _timer()
        measure = traced is not None and (learn_benefit or (choice is not None and self.benefit_selector.wants_measurement(
            frame_elements.names, choice, self.frames_rendered)))
        combined = raster.shade(traced, measure_change=measure)
        # The passes made from the image are frame work: timed with the composite (no stage held them).
        passes = self.frame_passes(snapshot, raster, combined, selected, candidate)
        # PHRT Rate: per pixel the rate its traced terms came at (0: raster), rows bottom to top.
        passes.rate = np.zeros((raster.height, raster.width), np.float32) if traced_frame.rate is None else traced_frame.rate
        passes.effect_rate = traced_frame.effect_rate or None
        composite_ms = _ms(start)
        # Uploading the traced results is part of the tracing's cost, which scales with the selection.
        traced_upload_ms = float(raster.stats.get("traced_upload_ms", 0.0)) if traced is not None else 0.0
        trace_ms += traced_upload_ms
        composite_ms = max(composite_ms - traced_upload_ms, 0.0)
        # The first draw of a lighting/composite configuration compiles its shaders (one-time).
        shade_setup_ms = float(raster.stats.get("shade_setup_ms", 0.0))

        if choice is not None:
            start = _timer()
            measured = item_benefit.measure(snapshot, layers, raster.traced_change(), traced, choice.chosen,
                                            element_bounds) if measure else None
            if warm and shade_setup_ms == 0.0:  # what measuring costs
                self.benefit_selector.observe_measure_cost(measure, composite_ms + (_ms(start) if measure else 0.0))
            self.benefit_selector.observe(frame_elements.names, choice, item_priors, measured, pixels)
            self.item_costs.tick(choice.eligible.any(axis=0), choice.chosen.any(axis=0) & (traced is not None))
            if traced is not None and self.frames_rendered > 0:  # the first frame compiles and builds
                if warm and self.cost_model.trace_overhead_ms() > 0 and self.item_costs.measured(choice.chosen):
                    self.benefit_selector.observe_time(selection.predicted_trace_ms,
                                                       max(trace_ms - upload_ms, 0.0))
                self.item_costs.observe(
                    frame_elements.names, expected_rays(area_px, effect_rays), traced_frame.item_rays,
                    choice.chosen, choice.rate, [counters.shadow_ms, counters.reflection_ms, counters.refraction_ms],
                    [counters.shadow_rays, counters.reflection_rays, counters.refraction_rays],
                    shadow_setup_ms=counters.shadow_setup_ms,
                    embree_ms=[counters.shadow_embree_ms, counters.reflection_embree_ms, counters.refraction_embree_ms],
                    reconstruct_ms=counters.reconstruct_ms, reconstructed_px=counters.reconstructed_px)
            select_ms += _ms(start)
        elif measure:
            # The error-aware relevance learns what tracing changed, measured on the GPU beside the
            # image (selection bookkeeping: select_ms).
            start = _timer()
            difference = benefit.measure_differences(snapshot, layers, raster.traced_change(), traced, selected,
                                                     element_bounds)
            self.benefit_model.observe(frame_elements.names, selected, difference, area_px)
            select_ms += _ms(start)

        total_ms = raster_ms + select_ms + trace_ms + composite_ms
        setup_ms = raster.setup_ms + upload_ms + shade_setup_ms
        if use_benefit and self.frames_rendered > 0 and (traced is None or warm):  # a steady frame, for the aim
            self.benefit_selector.observe_frame(max(total_ms - setup_ms, 0.0), selection.budget_ms,
                                                traced=traced is not None)
        # One-time work (Embree builds, shader compiles, uploads, new shadow maps, the first frame's selection:
        # every mesh's bounds, 80-130 ms on atrium, which held the next frame's T at 0) is not a per-frame cost.
        self.cost_model.observe(FrameStats(
            raster_ms=max(raster_ms - raster.setup_ms, 0.0), select_ms=select_ms if self.frames_rendered > 0 else None,
            composite_ms=None if shade_setup_ms > 0 else composite_ms,
            trace_ms=max(trace_ms - upload_ms, 0.0) if traced is not None else None,
            # The layers' read-back, the scene update, the uploads of the results: no effect's.
            trace_overhead_ms=max(trace_ms - upload_ms - counters.shadow_ms - counters.reflection_ms
                                  - counters.refraction_ms, 0.0) if traced is not None else None,
            effect_ms={"shadows": counters.shadow_ms, "reflections": counters.reflection_ms,
                       "refractions": counters.refraction_ms},
            effect_rays={"shadows": counters.shadow_rays, "reflections": counters.reflection_rays,
                         "refractions": counters.refraction_rays},
            element_rays=element_rays,  # the overhead's revision counts frames that could have traced:
            trace_wanted=may_trace and self.forced_selection is None and selection.time_left_ms > 0), selection)
        self.previous_selection = {name: bool(flag) for name, flag in zip(frame_elements.names, selected)}
        self.frames_rendered += 1
        stats = {
            "frame": snapshot.frame, "mode": mode, "total_ms": total_ms, "raster_ms": raster_ms,
            "select_ms": select_ms, "trace_ms": trace_ms, "composite_ms": composite_ms,
            "budget_ms": selection.budget_ms, "predicted_trace_ms": float(selection.predicted_trace_ms),
            "n_candidates": int(np.sum(frame_elements.candidate)),
            "n_visible": int(np.sum(np.asarray(selection.terms.visible, bool))),
            "n_selected": int(np.sum(selected)), "rays": counters.rays,
            "shadow_rays": counters.shadow_rays, "reflection_rays": counters.reflection_rays,
            "refraction_rays": counters.refraction_rays, "upload_ms": upload_ms,
            "setup_ms": setup_ms, "readback_ms": readback_ms,
            "gbuffer_ms": float(raster.stats.get("gbuffer_ms", raster.raster_ms)),
            "time_left_ms": float(selection.time_left_ms), "triangles": snapshot.n_triangles,
        }
        return FrameResult(passes=passes, stats=stats, selection=selection,
                           selection_rows=selection.rows(snapshot.frame), problems=list(snapshot.problems))

    # ------------------------------------------------------------------
    def _forced_rates(self, names):
        return None if self.forced_selection is None else forced_rates(self.forced_rates, names)

    @staticmethod
    def ray_pixels(snapshot, selected, effects):
        """(n + 1,) bool over element ids: the elements whose own pixels all rays leave from (reflections,
        refractions); None when shadows are traced (their receivers are anyone's pixels)."""
        wanted = traced_effects(snapshot.elements, selected, effects)
        if np.any(wanted["shadows"]) and any(light.cast_shadows for light in snapshot.lights):
            return None
        return np.r_[wanted["reflections"] | wanted["refractions"], False]

    def _prepare_tracing(self, snapshot, materials) -> float:
        """Build the Embree scenes and the meshes' bounds (``trace_rect``'s, for shadows), both kept
        for later frames; returns the ms spent (one-time work)."""
        start = _timer()
        if any(light.cast_shadows for light in snapshot.lights):  # (kept per mesh)
            self.element_bounds.scene_bounds(snapshot)
        self.trace_stage.prepare(snapshot, materials.casts_shadow[:len(snapshot.materials)])
        return _ms(start)

    def _no_time_to_trace(self, settings, raster_ms) -> bool:
        """A budget in ms whose time left after this frame's raster half cannot pay the trace
        stage's measured fixed overhead: the BENEFIT priors (a read-back) would buy nothing."""
        overhead = self.cost_model.trace_overhead_ms()
        return getattr(settings, "budget_at", None) is None and overhead > 0 and \
            self.cost_model.time_left(settings.budget_ms, max(raster_ms, 0.0)) <= overhead

    def _choose_items(self, selection, frame_elements, priors, pixels, effect_rays, tiers=False):
        """The BENEFIT selection of this frame: (ItemChoice, the SelectionResult it becomes).  The
        result keeps the paper's terms for the log; its elements' effect flags and rays per pixel
        are those traced, which the cost model learns from."""
        terms = selection.terms
        flags = flags_array({"shadows": frame_elements.shadows, "reflections": frame_elements.reflections,
                              "refractions": frame_elements.refractions}).astype(bool)
        competing = terms.candidate & terms.visible & terms.within_area
        eligible = flags & competing[:, None] & (pixels > 0)
        overhead = self.cost_model.trace_overhead_ms()
        rays, own = expected_rays(frame_elements.area_px, effect_rays), self.item_costs.cost_ratios(frame_elements.names)
        cost_ms = self.item_costs.predict(frame_elements.names, rays, own)
        time_left = self.benefit_selector.aimed_time_left(selection.time_left_ms, selection.budget_ms)
        # Q weighs the choice (value per ms / Q); the frame is planned with the ms items take.
        choice = self.benefit_selector.choose(frame_elements.names, eligible, pixels, priors, frame_elements.priority
                                              / np.maximum(frame_elements.rt_cost, selection_terms.MIN_RT_COST),
                                              cost_ms, time_left, overhead, tiers=tiers,
                                              fixed_ms=self.item_costs.fixed_ms(),
                                              unmeasured=self.item_costs.unmeasured(),
                                              visible=terms.visible,
                                              tier_costs=self.item_costs.tier_costs(
                                                  frame_elements.names, rays, pixels, own) if tiers else None)
        chosen = choice.chosen
        selected = chosen.any(axis=1)
        forced = heuristic.force_selection(selection, [name for name, flag in zip(frame_elements.names, selected)
                                                       if flag])
        traced_flags = np.where(selected[:, None], chosen, flags)
        as_traced = dataclass_replace(
            frame_elements, shadows=traced_flags[:, 0], reflections=traced_flags[:, 1],
            refractions=traced_flags[:, 2], rays_per_pixel=np.sum(effect_rays * traced_flags, axis=1))
        predicted = np.where(selected, np.sum(choice.chosen_cost_ms, axis=1), np.sum(choice.cost_ms, axis=1))
        trace = float(np.sum(choice.chosen_cost_ms)) + ((overhead + choice.fixed_ms) if np.any(selected) else 0.0)
        return choice, dataclass_replace(
            forced, elements=as_traced, predicted_ms=predicted, predicted_trace_ms=trace,
            effects=choice.effects, benefit_estimate=np.sum(choice.value, axis=1),
            item_rate=np.where(selected, np.min(np.where(chosen, choice.rate, np.inf), axis=1), 0.0))

    @staticmethod
    def frame_passes(snapshot, raster, combined, selected, candidate) -> FramePasses:
        n = len(snapshot.elements)
        # One key per pixel: 0 no element, 1..n the elements, n + 1 any other id (a corrupt one).
        key = np.asarray(raster.front_element).astype(np.int64)
        key += 1
        np.minimum(key.view(np.uint64), np.uint64(n + 1), out=key.view(np.uint64))
        candidate_flags = np.r_[False, candidate, False].astype(np.float32)
        selected_flags = np.r_[False, np.asarray(selected, bool), False].astype(np.float32)
        depth = np.where(np.isfinite(raster.view_depth), raster.view_depth, np.float32(1e10)).astype(np.float32,
                                                                                                    copy=False)
        if combined is not None:  # None: the image stayed on the GPU (the viewport draws it there)
            combined = shading.finite_rgba(combined)  # the read-back is this frame's own: made finite in place
        element_ids = np.r_[0.0, np.arange(1, n + 1), 0.0].astype(np.float32)  # 1-based, 0: none
        return FramePasses(
            combined=combined,
            depth=depth,
            normal=finite(raster.front_normal, dtype=np.float32),
            selected=selected_flags[key],
            candidate=candidate_flags[key],
            element=element_ids[key],
        )

    def _shadow_footprints(self, raster, snapshot, element_bounds, area_px):
        """Estimated shadow-ray count per element (pixels it can shadow, summed over lights),
        from a 1/FOOTPRINT_STEP^2 sub-sample of the front surfaces (from the resolve's view
        depth: no layer is read back before the selection)."""
        n = len(snapshot.elements)
        footprint = np.zeros(n)
        points = front_points(snapshot.camera, raster.view_depth, FOOTPRINT_STEP, self.pixel_grid)
        if len(points) == 0:
            return footprint
        scale = FOOTPRINT_STEP * FOOTPRINT_STEP
        casters = [index for index, element in enumerate(snapshot.elements)
                   if element.is_candidate and element.shadows and area_px[index] > 0
                   and element_bounds[index] is not None]
        for light in (light for light in snapshot.lights if light.cast_shadows and casters):
            footprint[casters] += scale * ShadowRegionIndex(light, points).counts([element_bounds[i] for i in casters])
        return footprint
