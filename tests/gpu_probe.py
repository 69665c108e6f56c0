"""Run a function inside a RenderEngine.render() call: the only GPU context in background mode."""
import bpy


class GPUProbe(bpy.types.RenderEngine):
    bl_idname = "PHRT_TEST_GPU_PROBE"
    bl_label = "PHRT GPU probe"
    bl_use_gpu_context = True
    job = None
    result = None
    error = None

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)

    def render(self, depsgraph):
        try:
            type(self).result = type(self).job(self, depsgraph)
        except Exception as error:  # re-raised by run_on_gpu
            type(self).error = error


def run_on_gpu(scene, job):
    """``job(engine, depsgraph)`` inside render(); returns its result, re-raises its exception."""
    previous = scene.render.engine
    GPUProbe.job, GPUProbe.result, GPUProbe.error = job, None, None
    bpy.utils.register_class(GPUProbe)
    try:
        scene.render.engine = GPUProbe.bl_idname
        bpy.ops.render.render()
    finally:
        scene.render.engine = previous
        bpy.utils.unregister_class(GPUProbe)
    if GPUProbe.error is not None:
        raise GPUProbe.error
    return GPUProbe.result
