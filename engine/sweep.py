"""Running the jobs of a sweep plan (``phrt_addon/plan.py``) through Blender.

:func:`execute_job` is the job function every executor calls: module level,
given only the plan's path and a job id, so it can run in this process
(``LocalExecutor``) or in a worker process elsewhere.  It skips a complete
job, writes the job's directory under a temporary name and renames it when
the job is complete.
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

from ..phrt_addon import plan as plan_module
from . import oracle as oracle_engine
from . import replay


# (scene, path, resolution) this process has rendered: its one-time costs are paid.
_WARM = set()


def _open_scene(plan):
    """Open the plan's scene; the first time in this process, render one throw-away frame so
    that no run pays the process's one-time costs (shader compiles, the driver's first draw,
    shadow maps, which stay cached) in its first frame while the others do not."""
    import tempfile

    from .. import cli
    cli._blender()
    with cli._quiet_stdout():
        cli.load_scene(plan.scene)
    import bpy
    scene = bpy.context.scene
    camera = replay.find_path(scene, plan.path)
    key = (plan.scene, plan.path, tuple(plan.resolution))
    if key not in _WARM:
        with tempfile.TemporaryDirectory(prefix="phrt-warm-up-") as folder, cli._quiet_stdout():
            replay.replay(scene, camera, (plan.frames[0], plan.frames[0]), "RAYTRACE", Path(folder) / "run",
                          images="none", resolution=tuple(plan.resolution), scene_label=plan.scene_label)
        _WARM.add(key)
    return scene, camera


def execute_job(plan_path, job_id) -> plan_module.JobOutcome:
    """Run job ``job_id`` of the plan at ``plan_path`` unless it is complete."""
    plan_path = Path(plan_path)
    folder = plan_path.parent
    plan = plan_module.read_plan(plan_path)
    job = plan.job(job_id)
    if plan_module.job_is_complete(plan, folder, job):
        return plan_module.JobOutcome(job.id, "skipped", message="complete")
    begin = time.perf_counter()
    for stale in folder.glob(f".{job.id}.partial-*"):
        shutil.rmtree(stale, ignore_errors=True)
    partial = plan_module.partial_dir(folder, job)
    scene, camera = _open_scene(plan)
    from .. import cli  # the package root (cli.py): scene loading and stdout handling
    try:
        with cli._quiet_stdout():
            message = _run(plan, folder, job, scene, camera, partial)
        plan_module.publish(partial, folder / job.id)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return plan_module.JobOutcome(job.id, "done", time.perf_counter() - begin, message)


def _run(plan, folder, job, scene, camera, partial) -> str:
    """Write the job's directory at ``partial``; returns a one-line account."""
    frames = (plan.frames[0], plan.frames[1])
    resolution = tuple(plan.resolution)
    if job.kind == "run":
        raster_id, raytrace_id = (plan_module.run_id(plan.scene_label, plan.path, mode)
                                  for mode in ("RASTER", "RAYTRACE"))
        result = replay.replay(scene, camera, frames, job.mode, partial, images="exr", resolution=resolution,
                               scene_label=plan.scene_label, budget_at=job.budget_at,
                               budget_search_dirs=[folder / raster_id, folder / raytrace_id],
                               overrides=job.overrides)
        if result.cancelled:
            raise RuntimeError(f"run {job.id} stopped after {result.frames_done} frames")
        message = f"{result.frames_done} frames, mean {result.summary['total_ms']['mean']:.0f} ms"
        if job.budget_at is not None:
            message += f", budget {result.summary['budget_ms']:.0f} ms"
    elif job.kind == "oracle":
        hybrids = {dependency: folder / dependency for dependency in job.depends_on
                   if plan.job(dependency).mode == "HYBRID"}
        reference = next(folder / dependency for dependency in job.depends_on
                         if plan.job(dependency).mode == "RAYTRACE")
        info = oracle_engine.run_oracle(scene, camera, reference, hybrids, partial, every=plan.oracle_every,
                                        resolution=resolution)
        message = f"{len(info['frames'])} sampled frames, {len(hybrids)} runs"
    else:
        raise ValueError(f"unknown job kind '{job.kind}'")
    return message
