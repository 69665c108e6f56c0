"""The engine's session: everything PHRT keeps between ``render()`` calls, in one object.

Blender makes a new ``RenderEngine`` instance for each F12 render and each frame of a
replay, so what must survive a frame cannot live on the instance.  As Cycles keeps
``engine.session``, PHRT keeps one ``EngineSession`` per Blender process (``current()``),
and every engine instance holds it as ``self.session``:

- ``resources``: the GPU objects (``gpu.resources.GPUResources``);
- ``meshes``, ``textures``: what ``extract`` converted, by content (bounded caches);
- ``renderers``: a ``FrameRenderer`` per scene for F12 renders outside a replay (Embree
  scenes, cost model, last selection);
- ``replay``: the active ``final.ReplayState`` (None outside a replay);
- ``last_frame``: the last frame's decisions, statistics and problems, which the N panel,
  the viewport overlay and ``phrt.export_selection_log`` read through ``last_frame()``;
- ``blas``: numpy's OpenBLAS, held to one thread while PHRT renders (``blas_threads``);
- the UI's bookkeeping: the candidate list's (``refreshing_candidates``, ``pending_refresh``) and the
  viewport overlay's draw handler (``overlay_handle``).

``release()`` drops all of it (file load, unregister, tests); nothing else in the add-on
keeps state at module level.
"""
from __future__ import annotations

import atexit
import queue
from dataclasses import dataclass, field

from ..phrt_addon.blas_threads import BlasThreads
from ..phrt_addon.cache import BoundedCache
from .gpu.resources import GPUResources

MESH_CACHE_SIZE = 4096  # converted meshes (triangles, corner normals, UVs), by content
TEXTURE_CACHE_SIZE = 32  # images read from Blender, linear and prepared (up to 64 MB each)
RENDERER_CACHE_SIZE = 4  # scenes rendered with F12 outside a replay


@dataclass
class LastFrame:
    """The last rendered frame, for the UI: selection rows, problems and frame statistics."""

    rows: list = field(default_factory=list)
    problems: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)

    def clear(self):
        self.rows, self.problems, self.stats = [], [], {}


def _close_renderer(_scene_name, renderer):
    renderer.close()


class EngineSession:
    def __init__(self):
        self.resources = GPUResources()
        self.meshes = BoundedCache(MESH_CACHE_SIZE)
        self.textures = BoundedCache(TEXTURE_CACHE_SIZE)
        self.renderers = BoundedCache(RENDERER_CACHE_SIZE, on_evict=_close_renderer)
        self.replay = None
        self.last_frame = LastFrame()
        self.refreshing_candidates = False  # the candidate list is being rebuilt: ignore its update callbacks
        self.pending_refresh = queue.SimpleQueue()  # scenes whose candidate list waits for the main thread
        self.overlay_handle = None  # the viewport overlay's draw handler (engine/viewport.py)
        self.blas = BlasThreads()  # numpy's BLAS, held to one thread while PHRT renders

    def renderer_for(self, scene_name: str):
        """The ``FrameRenderer`` of this frame: the replay's, else the scene's own."""
        if self.replay is not None:
            return self.replay.renderer
        renderer = self.renderers.get(scene_name)
        if renderer is None:
            from ..phrt_addon.frame import FrameRenderer
            renderer = self.renderers.put(scene_name, FrameRenderer())
        return renderer

    def release(self):
        """Forget everything (file load, unregister, tests): GPU objects, caches, renderers."""
        self.renderers.clear()
        self.resources.release()
        self.meshes.clear()
        self.textures.clear()
        if self.replay is not None:
            self.replay.renderer.close()
        self.replay = None


_SESSION = EngineSession()
# GPU objects still referenced when the interpreter ends crash Blender's own teardown (exit status
# 139 seen with bpy 5.0.1 when a shader outlived the process): drop them first.  atexit runs
# handlers last-registered first, so this runs before anything bpy registered on import.
atexit.register(_SESSION.resources.release)


def current() -> EngineSession:
    """The session of this Blender process."""
    return _SESSION


def last_frame() -> LastFrame:
    """The last rendered frame's decisions, statistics and problems (the UI's one accessor)."""
    return _SESSION.last_frame


def release():
    _SESSION.release()
