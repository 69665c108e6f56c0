"""A replay's first traced frame pays one-time work (the tracer's imports, first buffers) that the
cost model learns as its fixed trace overhead: a prudent start.  Before, when that overhead left no
time to trace, nothing was traced again and it was never corrected (atrium path1 at 0.25 of the
way: 54 ms learned, no trace for the rest of the replay).  Now it is revised every STALE_FRAMES
frames that could have traced, so tracing resumes and the overhead is learned again; frames with
no time left, or forced empty by the oracle, do not count."""
import time

import pytest

from phrt.phrt_addon.frame import FrameRenderer
from phrt.phrt_addon.raster.reference_raster import ReferenceRaster
from phrt.phrt_addon.select.cost_model import STALE_FRAMES
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
def test_a_cold_first_trace_that_prices_tracing_out_is_revised_until_tracing_resumes(cold_first_trace, selection):
    snapshot = mirror_scene("HYBRID")
    snapshot.settings.selection = selection
    gbuffer = ray_cast_gbuffer(snapshot)
    renderer = FrameRenderer(threads=1)
    try:
        first = _frame(renderer, snapshot, gbuffer)
        assert first.stats["n_selected"] >= 1 and first.stats["trace_ms"] >= COLD_S * 1000
        assert renderer.cost_model.trace_overhead_ms() >= 0.9 * COLD_S * 1000  # learned: a prudent start
        snapshot.settings.budget_ms = COLD_S * 1000 / 3  # time left, but less than that overhead
        traced_at = None
        for frame in range(1, 6 * STALE_FRAMES):
            if _frame(renderer, snapshot, gbuffer).stats["n_selected"] >= 1:
                traced_at = frame
                break
        # 400 ms halved every STALE_FRAMES frames fits a 133 ms budget after two revisions.
        assert traced_at is not None and 2 * STALE_FRAMES <= traced_at <= 3 * STALE_FRAMES + 1
        # The trace that resumed measured the overhead again: the cold one is gone.
        assert renderer.cost_model.trace_overhead_ms() < 0.1 * COLD_S * 1000
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
