"""A sweep's hybrid runs of one path rendered together, frame by frame (``phrt sweep --lockstep``).

This kind of machine (two shared cores, a CPU rasterizer) drifts by tens of percent within
minutes: in one sweep of eval-15 (atrium/path3) the raster half took 33 ms a frame in the raster
run and the three runs after it, and 40-46 ms in the six runs after those, so a budget that left
12 ms for tracing in one run left none in the next, whatever the selection.  Runs made one after
the other meet different machines, and the difference between two variants is then mostly the
hour's.  Here every hybrid run of a path (each budget and each selection variant) renders frame f
before any of them renders frame f + 1, each frame starting with the next run in turn: they meet
the machine in the same state, within a second of each other.

Each run is the very replay ``phrt sweep`` makes otherwise (``ReplayRun`` with the job's arguments,
its own frame renderer, cost model and logs, its folder written under a temporary name and
published when complete); what they share is the scene and the GPU's static geometry (uploaded
once for all of them).  The raster and raytrace runs (where a budget at F finds its milliseconds)
run before, the oracle after, as in a plain sweep; ``speed_vs_raster`` in ``sweep.csv`` says how
far the machine drifted between the raster run and the hybrid runs, the same for all of them.
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

from . import blender_process
from .sweep import SweepInterrupted, clear_dead_attempts, redo_reason, run_arguments, open_scene
from ..engine import session
from ..engine.runs import camera_path, replay
from ..engine.runs.interrupts import stop_on_signals
from ..phrt_addon.runs import plan as plan_module


def execute_group(plan_path, job_ids) -> list:
    """Run the hybrid run jobs ``job_ids`` (one path of the plan at ``plan_path``) in lockstep;
    complete ones are skipped.  One outcome per job.  Bad input fails every job of the group with
    its one-line message; a signal stops the group between frames (``SweepInterrupted``, nothing of
    it kept); anything else raises (the caller records it)."""
    plan_path = Path(plan_path)
    folder = plan_path.parent
    begin = time.perf_counter()
    plan = plan_module.read_plan(plan_path)
    jobs = [plan.job(plan_module.check_job_id(job_id)) for job_id in job_ids]
    targets = {plan.target(job) for job in jobs}
    if len(targets) > 1 or any(job.kind != "run" or job.mode != "HYBRID" for job in jobs):
        raise ValueError("a lockstep group is the hybrid runs of one path")
    outcomes, todo = [], []
    try:
        for job in jobs:
            redo = redo_reason(plan, folder, job)
            if redo is None:
                outcomes.append(plan_module.JobOutcome(job.id, "skipped", message="complete"))
            else:
                todo.append((job, redo))
        if not todo:
            return outcomes
        for job, _ in todo:
            clear_dead_attempts(folder, job)
        scene, camera = open_scene(plan, todo[0][0])
        partials = [plan_module.partial_dir(folder, job) for job, _ in todo]
        try:
            with blender_process.quiet_stdout():
                results = _lockstep(plan, folder, [job for job, _ in todo], scene, camera, partials)
            for (job, _), partial in zip(todo, partials):
                plan_module.publish(partial, folder / job.id)
        except BaseException:
            for partial in partials:
                shutil.rmtree(partial, ignore_errors=True)
            raise
    except (blender_process.UserError, camera_path.ReplayError, plan_module.PlanError) as error:
        message = str(error).strip().splitlines()[0]
        return outcomes + [plan_module.JobOutcome(job.id, "failed", time.perf_counter() - begin, message)
                           for job, _ in todo]
    seconds = (time.perf_counter() - begin) / len(todo)  # the group's time, shared
    for (job, redo), result in zip(todo, results):
        message = f"{result.frames_done} frames in lockstep with {len(todo) - 1} other runs, " \
                  f"mean {result.summary['total_ms']['mean']:.0f} ms"
        if job.budget_at is not None:
            message += f", budget {result.summary['budget_ms']:.0f} ms"
        if redo != "no run yet":
            message = f"redone: {redo}; {message}"
        outcomes.append(plan_module.JobOutcome(job.id, "done", seconds, message))
    return outcomes


def _lockstep(plan, folder, jobs, scene, camera, partials) -> list:
    """Open a ``ReplayRun`` per job, render frame after frame, each frame every run (starting with
    the next run each frame), then finish them; returns their ``ReplayResult``s."""
    frames = (plan.frames[0], plan.frames[1])
    runs = []
    engine_session = session.current()
    try:
        for job, partial in zip(jobs, partials):
            runs.append(replay.ReplayRun(scene, camera, frames, job.mode, partial, **run_arguments(plan, folder, job)))
        received = []
        with stop_on_signals(received):
            index = 0
            while runs[0].remaining and not received:
                for offset in range(len(runs)):
                    run = runs[(index + offset) % len(runs)]
                    engine_session.replay = run.state  # the frame renderer this render uses
                    try:
                        run.step()
                    except replay.ReplayInterrupted:
                        received.append("SIGINT")  # Esc or a stopped render: the group stops
                    if received:
                        break
                index += 1
        if received:
            raise SweepInterrupted(received[0], jobs[0].id, runs[0].done)
    except BaseException:
        for run in reversed(runs):  # the last opened first: each restores what the one before it saw
            try:
                run.finish(cancelled=True)
            except ValueError:
                pass  # a run whose step failed closed itself
        raise
    # Finished in reverse order: the scene and numpy's BLAS threads come back as the first found them.
    return list(reversed([run.finish() for run in reversed(runs)]))


class LockstepExecutor:
    """``plan.LocalExecutor``'s order, except that the hybrid runs of each path run together
    (:func:`execute_group`) once the jobs they depend on are done; a run whose dependency failed is
    not run (status 'failed', saying which)."""

    def __init__(self, group=execute_group):
        self.group = group

    def run(self, plan_path, plan, execute, on_outcome=None):
        outcomes, failed, handled = [], set(), set()

        def record(outcome):
            if outcome.status == "failed":
                failed.add(outcome.job_id)
            handled.add(outcome.job_id)
            outcomes.append(outcome)
            if on_outcome is not None:
                on_outcome(outcome)

        order = plan.in_dependency_order()
        for job in order:
            if job.id in handled:
                continue
            missing = [dependency for dependency in job.depends_on if dependency in failed]
            if missing:
                record(plan_module.JobOutcome(job.id, "failed", message=f"not run: {', '.join(missing)} failed"))
                continue
            if job.kind == "run" and job.mode == "HYBRID":
                # The hybrid runs of this path whose dependencies are all handled, none failed.
                group = [other for other in order if other.id not in handled and other.kind == "run"
                         and other.mode == "HYBRID" and plan.target(other) == plan.target(job)
                         and all(dependency in handled and dependency not in failed
                                 for dependency in other.depends_on)]
                begin = time.perf_counter()
                try:
                    results = self.group(str(plan_path), [other.id for other in group])
                except Exception as error:  # the group's failure must not hide what the other jobs did
                    results = [plan_module.JobOutcome(other.id, "failed", time.perf_counter() - begin,
                                                      f"{type(error).__name__}: {error}") for other in group]
                for outcome in results:
                    record(outcome)
                continue
            begin = time.perf_counter()
            try:
                outcome = execute(str(plan_path), job.id)
            except Exception as error:
                outcome = plan_module.JobOutcome(job.id, "failed", time.perf_counter() - begin,
                                                 f"{type(error).__name__}: {error}")
            record(outcome)
        return outcomes
