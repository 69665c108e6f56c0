"""What a Dask worker process does before its first PHRT job (docs/cluster.md).

``BlenderWorker`` is a Dask worker plugin, registered by ``phrt sweep
--workers/--scheduler`` on every worker of the cluster (and on workers that
join or restart later).  Its ``setup`` runs on the worker's event loop, in the
process's main thread: it imports ``bpy`` there, which makes that thread
Blender's main thread (where jobs open their .blend files, see
``phrt_addon/executors.on_main_thread``), and registers the PHRT add-on, which
also unregisters it when the process ends so that the worker exits cleanly.

Jobs render in the worker's task thread, where each render has a GPU context
of its own; file loads and the exit, on the main thread, free the GPU objects
PHRT cached (shaders, batches, textures).  Freeing a shader needs a current GPU
context (Blender 4.5 aborts otherwise: "Couldn't find current GLX or EGL
context"), so ``setup`` renders one 8x8 Workbench frame of a throw-away scene
on the main thread: that leaves Blender's main GPU context current there for
the life of the process (checked on 4.5, 5.0 and 5.2).

A LocalCluster's worker processes are spawned with the ``sys.path`` of the
process that starts them; when that one has imported ``bpy``, it holds
Blender's script folders, and ``scripts/modules`` has a package named ``bpy``
that would shadow the module: they are dropped before ``bpy`` is imported
(importing it adds them again).  The worker's standard output goes to its
standard error, and to nothing once the process ends: Blender prints progress
there, and a LocalCluster's workers share the ``phrt`` command's standard
output, which is kept for its own lines.

Not under ``engine/`` (whose ``__init__`` imports ``bpy``): the plugin is
unpickled on the worker before ``bpy`` may be imported.  Imports Dask: only
loaded when a Dask executor is used.
"""
from __future__ import annotations

import atexit
import os
import re
import sys

from distributed import WorkerPlugin

_BLENDER_SCRIPTS = re.compile(r"[\\/]scripts[\\/](startup|modules|freestyle[\\/]modules|addons[\\/]modules|addons_core)"
                              r"[\\/]?$")


class BlenderWorker(WorkerPlugin):
    name = "phrt-blender"
    idempotent = True  # set up once per worker process, however many clients register it

    def setup(self, worker):
        if "bpy" not in sys.modules:
            sys.path[:] = [entry for entry in sys.path if not _BLENDER_SCRIPTS.search(entry)]
        sys.stdout.flush()
        os.dup2(2, 1)
        from . import blender_process
        blender_process.import_blender()
        bpy = blender_process.blender()
        with blender_process.quiet_stdout():
            _main_thread_gpu_context(bpy)
        atexit.register(blender_process.quiet_exit)  # Blender's "Not freed memory blocks" (4.5) at exit


def _main_thread_gpu_context(bpy):
    """Render an 8x8 Workbench frame of a throw-away scene on this (the main) thread."""
    name = "phrt-worker-gpu-context"
    scene = bpy.data.scenes.new(name)
    camera_data = bpy.data.cameras.new(name)
    camera = bpy.data.objects.new(name, camera_data)
    try:
        scene.collection.objects.link(camera)
        scene.camera = camera
        scene.render.engine = "BLENDER_WORKBENCH"
        scene.render.resolution_x = scene.render.resolution_y = 8
        scene.render.resolution_percentage = 100
        bpy.ops.render.render(scene=scene.name)
    finally:
        bpy.data.objects.remove(camera)
        bpy.data.cameras.remove(camera_data)
        bpy.data.scenes.remove(scene)

