"""Final (F12 / animation / background) rendering of a PHRT frame.

depsgraph -> snapshot (``extract``) -> GPU G-buffer and shadow maps (``raster``)
-> selection, trace, composite (``phrt_addon.frame``) -> render result passes,
and, when a replay session is active, the run logs.

State that must survive between frames lives outside the engine instance, in a
``ReplaySession`` (one per replay: frame renderer with its Embree scenes, cost
model and last selection, plus the run log), so a replay made of separate
``render.render()`` calls and an animation render behave the same.
"""
from __future__ import annotations

import sys
import time
import traceback

import numpy as np

from ..phrt_addon.frame import FrameRenderer
from ..phrt_addon.problems import ProblemLog
from ..phrt_addon.schema import PASS_FIELDS
from . import extract, gpu_resources, raster

_STANDALONE = {}  # scene name -> FrameRenderer when no replay session is active
ACTIVE_SESSION = None


def log_exception(error):
    traceback.print_exception(type(error), error, error.__traceback__, file=sys.stderr)


def release_caches():
    """Forget every cache (unregister, tests)."""
    global ACTIVE_SESSION
    for renderer in _STANDALONE.values():
        renderer.close()
    _STANDALONE.clear()
    gpu_resources.RESOURCES.release()
    extract.MESH_CACHE._entries.clear()
    extract.TEXTURE_CACHE.clear()
    if ACTIVE_SESSION is not None:
        ACTIVE_SESSION.renderer.close()
    ACTIVE_SESSION = None


class ReplaySession:
    """What a replay carries from frame to frame. Activate with ``with session:``."""

    def __init__(self, on_frame=None, settings_override=None, camera=None):
        self.renderer = FrameRenderer()
        self.on_frame = on_frame  # callback(result, snapshot) after each frame
        self.settings_override = settings_override
        self.camera = camera
        self.last_result = None

    def __enter__(self):
        global ACTIVE_SESSION
        ACTIVE_SESSION = self
        return self

    def __exit__(self, *exc):
        global ACTIVE_SESSION
        ACTIVE_SESSION = None
        self.renderer.close()
        # End of the replay: its GPU resources (meshes, shadow maps, targets) are dropped here.
        gpu_resources.RESOURCES.release(keep_shaders=True)
        return False


# The last frame's decisions and problems, for the N panel and the viewport overlay.
LAST_FRAME = {"rows": [], "problems": [], "stats": {}}


def rasterize(snapshot):
    """The GPU stage of a frame (needs a GPU context): G-buffer, its resolve read-back, and the
    shadow maps that are missing.  Returns the drawn ``raster.GPUFrame``."""
    frame = raster.GPUFrame(snapshot)
    frame.draw()
    return frame


class FinalRender:
    def __init__(self, engine):
        self.engine = engine
        self.problems = ProblemLog()  # one engine instance renders all frames of an animation

    def render(self, depsgraph):
        engine = self.engine
        scene = depsgraph.scene_eval
        session = ACTIVE_SESSION
        start = time.perf_counter()
        snapshot = extract.extract(depsgraph, camera_override=session.camera if session else None,
                                   settings_override=session.settings_override if session else None)
        # Each problem is told once per replay or animation render, not on every frame.
        problem_log = session.renderer.problems if session is not None else self.problems
        for problem in problem_log.report(snapshot.problems, snapshot.frame):
            engine.report({"WARNING"}, f"PHRT: {problem}")
        extract_ms = (time.perf_counter() - start) * 1000.0
        width, height = snapshot.camera.width, snapshot.camera.height
        if session is not None:
            renderer = session.renderer
        else:
            renderer = _STANDALONE.get(scene.name)
            if renderer is None:
                renderer = _STANDALONE[scene.name] = FrameRenderer()

        engine.update_stats("PHRT", "Raster")
        gpu_frame = rasterize(snapshot)
        # No early return on test_break(): Blender 5.0.1 crashes saving a multilayer EXR of a
        # render that wrote no result, and a frame takes well under a second to finish.

        engine.update_stats("PHRT", "Selection, tracing, compositing")
        result = renderer.render(snapshot, gpu_frame)
        result.stats["extract_ms"] = extract_ms
        self._write(result, width, height)
        LAST_FRAME["rows"] = result.selection_rows
        LAST_FRAME["problems"] = list(snapshot.problems)
        LAST_FRAME["stats"] = dict(result.stats)
        if session is not None:
            session.last_result = result
            if session.on_frame is not None:
                session.on_frame(result, snapshot)
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
                flat = np.ascontiguousarray(np.nan_to_num(array), dtype=np.float32).ravel()
                expected = width * height * render_pass.channels
                if flat.size != expected:
                    raise RuntimeError(f"pass {name}: {flat.size} values for {expected}")
                render_pass.rect.foreach_set(flat)
        finally:
            engine.end_result(render_result)
