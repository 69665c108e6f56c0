"""Final (F12 / animation / background) rendering of a PHRT frame.

depsgraph -> snapshot (``extract``) -> GPU G-buffer and shadow maps (``gpu.frame``)
-> selection, trace, composite (``phrt_addon.frame``) -> render result passes,
and, when a replay session is active, the run logs.

State that must survive between frames lives outside the engine instance, in the
engine's session (``engine/session.py``) and, during a replay, in a ``ReplayState``
(one per replay: frame renderer with its Embree scenes, cost model and last
selection), so a replay made of separate ``render.render()`` calls and an animation
render behave the same.
"""
from __future__ import annotations

import sys
import time
import traceback

import numpy as np

from ..phrt_addon.frame import FrameRenderer
from ..phrt_addon.problems import ProblemLog
from ..phrt_addon.schema import PASS_FIELDS
from . import extract, session
from .gpu.frame import GPUFrame


def log_exception(error):
    traceback.print_exception(type(error), error, error.__traceback__, file=sys.stderr)


def release_caches():
    """Forget every cache (file load, unregister, tests): ``session.release()``."""
    session.release()


class ReplayState:
    """What a replay (or the oracle's renders) carries from frame to frame: the frame renderer,
    the settings and camera it renders with, the last result.  Activate with ``with state:``."""

    def __init__(self, on_frame=None, settings_override=None, camera=None):
        self.renderer = FrameRenderer()
        self.on_frame = on_frame  # callback(result, snapshot) after each frame
        self.settings_override = settings_override
        self.camera = camera
        self.last_result = None

    def __enter__(self):
        session.current().replay = self
        # numpy's BLAS on one thread for the whole replay: its idle threads spin between frames
        # too, on the cores the GPU driver and Embree render with (phrt_addon/blas_threads.py).
        self._blas = session.current().blas.limited(1)
        self._blas.__enter__()
        return self

    def __exit__(self, *exc):
        engine_session = session.current()
        engine_session.replay = None
        blas, self._blas = getattr(self, "_blas", None), None
        if blas is not None:
            blas.__exit__(None, None, None)
        self.renderer.close()
        # End of the replay: its GPU resources (meshes, shadow maps, targets) are dropped here.
        engine_session.resources.release(keep_shaders=True)
        return False


def active_replay():
    """The ``ReplayState`` of the replay being rendered, or None."""
    return session.current().replay


def rasterize(snapshot):
    """The GPU stage of a frame (needs a GPU context): G-buffer, its resolve read-back, and the
    shadow maps that are missing.  Returns the drawn ``GPUFrame``."""
    frame = GPUFrame(snapshot)
    frame.draw()
    return frame


class FinalRender:
    def __init__(self, engine):
        self.engine = engine
        self.problems = ProblemLog()  # one engine instance renders all frames of an animation

    def render(self, depsgraph):
        engine = self.engine
        scene = depsgraph.scene_eval
        engine_session = session.current()
        replay = engine_session.replay
        start = time.perf_counter()
        snapshot = extract.extract(depsgraph, camera_override=replay.camera if replay else None,
                                   settings_override=replay.settings_override if replay else None)
        # Each problem is told once per replay or animation render, not on every frame.
        problem_log = replay.renderer.problems if replay is not None else self.problems
        for problem in problem_log.report(snapshot.problems, snapshot.frame):
            engine.report({"WARNING"}, f"PHRT: {problem}")
        extract_ms = (time.perf_counter() - start) * 1000.0
        width, height = snapshot.camera.width, snapshot.camera.height
        renderer = engine_session.renderer_for(scene.name)

        engine.update_stats("PHRT", "Raster")
        gpu_frame = rasterize(snapshot)
        # No early return on test_break(): Blender 5.0.1 crashes saving a multilayer EXR of a
        # render that wrote no result, and a frame takes well under a second to finish.

        engine.update_stats("PHRT", "Selection, tracing, compositing")
        result = renderer.render(snapshot, gpu_frame)
        result.stats["extract_ms"] = extract_ms
        self._write(result, width, height)
        last = engine_session.last_frame
        last.rows, last.problems, last.stats = result.selection_rows, list(snapshot.problems), dict(result.stats)
        if replay is not None:
            replay.last_result = result
            if replay.on_frame is not None:
                replay.on_frame(result, snapshot)
        engine.update_stats("PHRT", f"{result.stats['total_ms']:.0f} ms, "
                                    f"{result.stats['n_selected']}/{result.stats['n_visible']} traced")

    def _write(self, result, width, height):
        engine = self.engine
        render_result = engine.begin_result(0, 0, width, height)
        try:
            layer = render_result.layers[0]
            passes = result.passes
            for name, field in PASS_FIELDS.items():
                array = getattr(passes, field)
                render_pass = layer.passes.find_by_name(name, "")
                if render_pass is None or array is None:
                    continue
                flat = np.ascontiguousarray(array, dtype=np.float32).ravel()
                if not np.isfinite(flat).all():  # the passes are built finite: this is the last guard
                    flat = np.nan_to_num(flat)
                expected = width * height * render_pass.channels
                if flat.size != expected:
                    raise RuntimeError(f"pass {name}: {flat.size} values for {expected}")
                render_pass.rect.foreach_set(flat)
        finally:
            engine.end_result(render_result)
