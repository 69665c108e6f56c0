"""A replay's first traced frame is one-time work (the tracer's imports, first buffers): the cost
model's fixed trace overhead and per-ray costs, the BENEFIT margin and item costs learn from the
frames after it only.  Before, its tens of ms were learned as a fixed overhead charged on every
later frame: at small budgets no time was left to trace again, so it was never corrected.  And
that overhead is revised only for frames that could have traced with time left."""
import time

import pytest

from phrt.phrt_addon.frame import FrameRenderer
from phrt.phrt_addon.raster.reference_raster import ReferenceRaster
from phrt.phrt_addon.select.cost_model import STALE_FRAMES, CostModel
from phrt.phrt_addon.trace import stage

from test_frame import mirror_scene, ray_cast_gbuffer

COLD_S = 0.4  # what the first trace's one-time work is made to take here


@pytest.fixture
def cold_first_trace(monkeypatch):
    """The trace stage's first run of each renderer takes COLD_S longer (as an import would)."""
    run = stage.TraceStage.run
    seen = set()

    def slow_first(self, *args, **kwargs):
        if id(self) not in seen:
            seen.add(id(self))
            time.sleep(COLD_S)
        return run(self, *args, **kwargs)

    monkeypatch.setattr(stage.TraceStage, "run", slow_first)


def _frame(renderer, snapshot, gbuffer):
    return renderer.render(snapshot, ReferenceRaster(snapshot, gbuffer))


@pytest.mark.parametrize("selection", ["PAPER", "BENEFIT"])
def test_the_first_traced_frame_teaches_no_trace_cost(cold_first_trace, selection):
    raster, hybrid = mirror_scene("RASTER"), mirror_scene("HYBRID")
    hybrid.settings.selection = selection
    gbuffer = ray_cast_gbuffer(hybrid)
    renderer = FrameRenderer(threads=1)
    try:
        assert _frame(renderer, raster, gbuffer).stats["n_selected"] == 0  # the replay's first frame traces nothing
        first = _frame(renderer, hybrid, gbuffer)  # its first traced frame
        assert first.stats["n_selected"] >= 1 and first.stats["trace_ms"] >= COLD_S * 1000
        model = renderer.cost_model
        assert model.trace_overhead_ms() == 0.0  # nothing learned yet
        assert model.ms_per_ray() == CostModel().ms_per_ray()  # the priors still
        assert not any(renderer.item_costs.samples.values())
        second = _frame(renderer, hybrid, gbuffer)
        assert second.stats["n_selected"] >= 1
        # Learned from the second frame alone: far below the first frame's one-time work.
        assert 0.0 < model.trace_overhead_ms() <= second.stats["trace_ms"] < COLD_S * 1000
        if selection == "BENEFIT":  # one sample per traced effect: the second frame's
            assert max(len(samples) for samples in renderer.item_costs.samples.values()) == 1
    finally:
        renderer.close()


def test_frames_without_time_left_or_forced_empty_do_not_revise_the_overhead():
    snapshot = mirror_scene("HYBRID")
    gbuffer = ray_cast_gbuffer(snapshot)
    renderer = FrameRenderer(threads=1)
    try:
        for _ in range(3):
            _frame(renderer, snapshot, gbuffer)
        learned = renderer.cost_model.trace_overhead_ms()
        assert learned > 0.0
        renderer.forced_selection = frozenset()  # the oracle's raster frames
        for _ in range(2 * STALE_FRAMES):
            assert _frame(renderer, snapshot, gbuffer).stats["n_selected"] == 0
        renderer.forced_selection = None
        snapshot.settings.budget_ms = 0.0  # no time left after the raster half
        for _ in range(2 * STALE_FRAMES):
            assert _frame(renderer, snapshot, gbuffer).stats["n_selected"] == 0
        assert renderer.cost_model.trace_overhead_ms() == learned
    finally:
        renderer.close()
