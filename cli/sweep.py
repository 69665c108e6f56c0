"""Running the jobs of a sweep plan (``phrt_addon/runs/plan.py``) through Blender.

:func:`execute_job` is the job function every executor calls: module level,
given only the plan's path and a job id, so it can run in this process
(``LocalExecutor``) or in a worker process elsewhere (``DaskExecutor``, from
:func:`make_executor`).  It skips a complete job, writes the job's directory
under a temporary name and renames it when the job is complete.  Bad input
(a missing .blend or camera path, an unsafe job id) makes a failed outcome with its one-line
message; anything else raises, and a Dask executor retries it.  A run is skipped only when its
recorded work is the job's (``plan.run_redo_reason``): otherwise it is redone and its outcome
says why (``redone: frames 1-3 -> 4-6``).
:func:`run_plan` runs a plan's jobs and writes the report of its runs.
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

from . import blender_process
from ..phrt_addon.runs import executors
from ..phrt_addon.report import oracle as oracle_module
from ..phrt_addon.runs import plan as plan_module
from ..engine.runs import oracle as oracle_engine
from ..engine.runs import replay
from ..engine.runs import camera_path


# (scene, path, resolution) this process has rendered: its one-time costs are paid.
_WARM = set()


class SweepInterrupted(BaseException):
    """A signal (SIGINT, SIGTERM) stopped a run of the sweep: the whole sweep stops (the runs complete
    so far stay, and running the same command again resumes).  A BaseException, so that the
    executor, which records an ordinary failure and goes on with the next job, lets it through."""

    def __init__(self, signal_name: str, job_id: str, frames_done: int):
        super().__init__(f"{signal_name} during {job_id} ({frames_done} frames done)")
        self.signal_name, self.job_id, self.frames_done = signal_name, job_id, frames_done


def _load(scene_name):
    """Register PHRT and open ``scene_name`` (a .blend path or a sample scene name)."""
    blender_process.blender()
    with blender_process.quiet_stdout():
        blender_process.load_scene(scene_name)


def open_scene(plan, job):
    """Open the job's scene (on the main thread: Blender opens files only there); the first time in
    this process, render one throw-away frame so that no run pays the process's one-time costs
    (shader compiles, the driver's first draw, shadow maps, which stay cached) in its first frame
    while the others do not."""
    import tempfile

    scene_name, label, path = plan.target(job)
    executors.on_main_thread(_load, scene_name)
    import bpy
    scene = bpy.context.scene
    camera = camera_path.find_path(scene, path)
    key = (scene_name, path, tuple(plan.resolution))
    if key not in _WARM:
        with tempfile.TemporaryDirectory(prefix="phrt-warm-up-") as folder, blender_process.quiet_stdout():
            replay.replay(scene, camera, (plan.frames[0], plan.frames[0]), "RAYTRACE", Path(folder) / "run",
                          images="none", resolution=tuple(plan.resolution), scene_label=label)
        _WARM.add(key)
    return scene, camera


def redo_reason(plan, folder, job) -> str | None:
    """Why ``job`` runs (``no run yet``, ``frames 1-3 -> 4-6``...), None when it is complete: a run
    only when its recorded work is the job's (``plan.run_redo_reason``)."""
    if job.kind == "run":
        scene_name, _, _ = plan.target(job)
        wanted = plan_module.wanted_work(plan, job, blender_process.scene_file(scene_name))
        return plan_module.run_redo_reason(folder / job.id, plan, wanted)
    return None if plan_module.job_is_complete(plan, folder, job) else "no run yet"


def clear_dead_attempts(folder, job):
    """Remove what an attempt of ``job`` that died left."""
    for stale in plan_module.dead_attempts(folder, job):
        shutil.rmtree(plan_module.inside(folder, stale), ignore_errors=True)


def execute_job(plan_path, job_id) -> plan_module.JobOutcome:
    """Run job ``job_id`` of the plan at ``plan_path`` unless it is complete."""
    plan_path = Path(plan_path)
    folder = plan_path.parent
    begin = time.perf_counter()
    try:
        plan = plan_module.read_plan(plan_path)
        job = plan.job(plan_module.check_job_id(job_id))
        redo = redo_reason(plan, folder, job)
        if redo is None:
            return plan_module.JobOutcome(job.id, "skipped", message="complete")
        clear_dead_attempts(folder, job)
        partial = plan_module.partial_dir(folder, job)
        scene, camera = open_scene(plan, job)
        try:
            with blender_process.quiet_stdout():
                message = _run(plan, folder, job, scene, camera, partial)
            plan_module.publish(partial, folder / job.id)
        except BaseException:
            shutil.rmtree(partial, ignore_errors=True)
            raise
    except (blender_process.UserError, camera_path.ReplayError, plan_module.PlanError) as error:
        # bad input: retrying cannot help
        return plan_module.JobOutcome(job_id, "failed", time.perf_counter() - begin,
                                      str(error).strip().splitlines()[0])
    if redo not in (None, "no run yet"):
        message = f"redone: {redo}; {message}"
    return plan_module.JobOutcome(job.id, "done", time.perf_counter() - begin, message)


def run_arguments(plan, folder, job) -> dict:
    """The keyword arguments of a run job's replay (``replay.replay`` or ``replay.ReplayRun``): EXR
    images at the plan's resolution, its budget, its references (the plan's raster and raytrace
    runs of its path, where a budget at F finds its milliseconds) and its settings."""
    _, label, path = plan.target(job)
    references = [dependency for dependency in job.depends_on
                  if plan.job(dependency).mode in ("RASTER", "RAYTRACE")]
    if not references:
        references = [plan_module.run_id(label, path, mode) for mode in ("RASTER", "RAYTRACE")]
    return {"images": plan_module.run_images(job), "resolution": tuple(plan.resolution), "scene_label": label,
            "budget_at": job.budget_at, "budget_ms": job.budget_ms,
            "budget_search_dirs": [folder / reference for reference in references], "overrides": job.overrides}


def run_message(job, result, how="") -> str:
    """'48 frames{how}, mean 116 ms, budget 128 ms': a finished run's outcome line."""
    message = f"{result.frames_done} frames{how}, mean {result.summary['total_ms']['mean']:.0f} ms"
    if job.budget_at is not None:
        message += f", budget {result.summary['budget_ms']:.0f} ms"
    return message


def _run(plan, folder, job, scene, camera, partial) -> str:
    """Write the job's directory at ``partial``; returns a one-line account."""
    frames = (plan.frames[0], plan.frames[1])
    resolution = tuple(plan.resolution)
    if job.kind == "run":
        result = replay.replay(scene, camera, frames, job.mode, partial, **run_arguments(plan, folder, job))
        if result.cancelled and result.signal:
            raise SweepInterrupted(result.signal, job.id, result.frames_done)
        if result.cancelled:
            raise RuntimeError(f"run {job.id} stopped after {result.frames_done} frames")
        message = run_message(job, result)
    elif job.kind == "oracle":
        hybrids = {dependency: folder / dependency for dependency in job.depends_on
                   if plan.job(dependency).mode == "HYBRID"}
        reference = next(folder / dependency for dependency in job.depends_on
                         if plan.job(dependency).mode == "RAYTRACE")
        # The shared time from the raster run rendered with the hybrid runs (lockstep), else the first.
        raster = plan_module.shared_raster(plan, folder, job)
        info = oracle_engine.run_oracle(scene, camera, reference, hybrids, partial, raster_dir=raster,
                                        every=plan.oracle_every, resolution=resolution)
        message = f"{len(info['frames'])} sampled frames, {len(hybrids)} runs"
    else:
        raise ValueError(f"unknown job kind '{job.kind}'")
    return message


def make_executor(workers=None, scheduler=None, **options):
    """``plan.LocalExecutor`` by default; a ``DaskExecutor`` on a LocalCluster of ``workers`` processes
    or on the cluster at ``scheduler``, whose workers get PHRT set up (``cli/dask_worker.py``).
    ``executors.ExecutorError`` when both are given, or Dask is missing."""
    if workers is None and scheduler is None:
        return executors.make_executor()
    executors.make_executor(workers, scheduler)  # checks the options before importing Dask
    executors.import_distributed()
    from .dask_worker import BlenderWorker
    return executors.make_executor(workers, scheduler, plugins=[BlenderWorker()], **options)


def run_plan(plan_path, plan, executor, on_outcome=None):
    """Run the plan's jobs with ``executor`` (complete ones are skipped) and write the report of its
    complete runs to ``DIR/report/``, failed jobs listed with their one-line messages.

    Returns ``(outcomes, report files or None, why there is no report or None)``."""
    from ..phrt_addon import report
    folder = Path(plan_path).parent
    outcomes = executor.run(plan_path, plan, execute_job, on_outcome=on_outcome)
    complete = [folder / job.id for job in plan.reported_runs if plan_module.run_is_complete(folder / job.id, plan)]
    if not complete:
        return outcomes, None, "no run is complete"
    failures = [(outcome.job_id, outcome.message) for outcome in outcomes if outcome.status == "failed"]
    try:
        files = report.build_report(complete, out_dir=folder / plan_module.REPORT_DIR,
                                    oracle_dir=folder / oracle_module.ORACLE_DIR, failures=failures)
    except ValueError as error:
        return outcomes, None, str(error).splitlines()[0]
    return outcomes, files, None  # OSError (a full disk) propagates: the caller says it in one line
