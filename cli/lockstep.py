"""A sweep's hybrid runs of one path rendered together, frame by frame (``phrt sweep --lockstep``).

This kind of machine (two shared cores, a CPU rasterizer) drifts by tens of percent within
minutes: in one sweep of eval-15 (atrium/path3) the raster half took 33 ms a frame in the raster
run and the three runs after it, and 40-46 ms in the six runs after those, so a budget that left
12 ms for tracing in one run left none in the next, whatever the selection.  Runs made one after
the other meet different machines, and the difference between two variants is then mostly the
hour's.  Here every hybrid run of a path (each budget and each selection variant) renders frame f
before any of them renders frame f + 1, each frame starting with the next run in turn: they meet
the machine in the same state, within one round of the group of each other (a few seconds for 9
runs at 320x240).  A run that fails (an error in a frame, its render stopped) fails alone; the
others go on.

Each run is the very replay ``phrt sweep`` makes otherwise (``ReplayRun`` with the job's arguments,
its own frame renderer, cost model and logs, its folder written under a temporary name and
published when complete); what they share is the scene and the GPU's static geometry (uploaded
once for all of them).  The raster and raytrace runs (where a budget at F finds its milliseconds)
run before, the oracle after, as in a plain sweep.  A second raster run (``plan.GROUP_RASTER``) is
rendered in the group: the oracle's shared time (its budget minus what every variant spends on the
raster half and the composite) comes from it, measured on the machine the hybrid runs met, not
minutes before (eval-17: the group's raster half 2.7-8.8 ms slower than the first raster run's on
two paths, 0.7-2.4 ms faster on a third, against 8-47 ms of time for tracing).
``speed_vs_raster`` in ``sweep.csv`` says how
far the machine drifted between the raster run and the hybrid runs, the same for all of them, and
``summary.json``'s ``lockstep_runs`` (``sweep.csv``'s column of that name) how many runs (the group
raster run included) a run was
rendered together with (absent: one after the other; a run redone alone later has 1).
"""
from __future__ import annotations

import shutil
import time
from pathlib import Path

from . import blender_process
from .sweep import SweepInterrupted, clear_dead_attempts, open_scene, redo_reason, run_arguments, run_message
from ..engine import session
from ..engine.runs import camera_path, replay
from ..engine.runs.interrupts import stop_on_signals
from ..phrt_addon.runs import plan as plan_module


def execute_group(plan_path, job_ids, on_frame=None) -> list:
    """Run the hybrid run jobs ``job_ids`` (one path of the plan at ``plan_path``) in lockstep;
    complete ones are skipped.  One outcome per job: a run that fails (bad input, an error in one
    of its frames, its render stopped) fails alone, the others go on and are published.  A signal
    stops the group between frames (``SweepInterrupted``, nothing of it kept).  ``on_frame(done,
    total, runs)`` after each round: frames every run has rendered, of ``total``."""
    plan_path = Path(plan_path)
    folder = plan_path.parent
    begin = time.perf_counter()
    plan = plan_module.read_plan(plan_path)
    jobs = [plan.job(plan_module.check_job_id(job_id)) for job_id in job_ids]
    if len({plan.target(job) for job in jobs}) > 1 or not all(plan_module.in_lockstep_group(job) for job in jobs):
        raise ValueError("a lockstep group is the hybrid runs of one path (and its group's raster run)")
    outcomes, todo = {}, []
    try:
        for job in jobs:
            redo = redo_reason(plan, folder, job)
            if redo is None:
                outcomes[job.id] = plan_module.JobOutcome(job.id, "skipped", message="complete")
            else:
                todo.append((job, redo))
        for job, _ in todo:
            clear_dead_attempts(folder, job)
        scene, camera = open_scene(plan, todo[0][0]) if todo else (None, None)
    except (blender_process.UserError, camera_path.ReplayError, plan_module.PlanError) as error:
        message = str(error).strip().splitlines()[0]
        return [outcomes.get(job.id) or plan_module.JobOutcome(job.id, "failed", time.perf_counter() - begin, message)
                for job in jobs]
    if todo:
        with blender_process.quiet_stdout():
            results = _lockstep(plan, folder, [job for job, _ in todo], scene, camera, on_frame)
        seconds = (time.perf_counter() - begin) / len(todo)  # the group's time, shared
        for (job, redo), (result, failure) in zip(todo, results):
            partial = plan_module.partial_dir(folder, job)
            if failure is not None:
                shutil.rmtree(partial, ignore_errors=True)
                outcomes[job.id] = plan_module.JobOutcome(job.id, "failed", seconds, failure)
                continue
            plan_module.publish(partial, folder / job.id)
            others = len(todo) - 1
            message = run_message(job, result, f" in lockstep with {others} other run{'' if others == 1 else 's'}")
            if redo != "no run yet":
                message = f"redone: {redo}; {message}"
            outcomes[job.id] = plan_module.JobOutcome(job.id, "done", seconds, message)
    return [outcomes[job.id] for job in jobs]


def step_in_lockstep(runs, before_step=None, stopped=lambda: False, after_round=None) -> dict:
    """Step ``runs`` (objects with ``remaining`` and ``step()``) frame by frame together: each round,
    every run still going renders its next frame, the round starting with the next run in turn (no
    run is always first or last).  A run whose step raises is left out from then on; the others go
    on.  ``before_step(run)`` runs before each step; ``stopped()`` is polled before each step (a
    signal: the caller stops the group); ``after_round(rounds)`` after each complete round.  Returns
    {index of a failed run: its exception}."""
    failed = {}
    count = len(runs)
    round_index = 0
    while not stopped():
        going = [index for index, run in enumerate(runs) if index not in failed and run.remaining]
        if not going:
            break
        for index in sorted(going, key=lambda index: (index - round_index) % count):
            if stopped():
                return failed
            if before_step is not None:
                before_step(runs[index])
            try:
                runs[index].step()
            except Exception as error:  # this run fails alone
                failed[index] = error
        round_index += 1
        if after_round is not None:
            after_round(round_index)
    return failed


def _failure(run, error) -> str:
    if isinstance(error, replay.ReplayInterrupted):
        return f"stopped while rendering: {run.done} frames done"
    return f"{type(error).__name__}: {str(error).strip().splitlines()[0] if str(error).strip() else ''}".rstrip(": ")


def _lockstep(plan, folder, jobs, scene, camera, on_frame=None) -> list:
    """Open a ``ReplayRun`` per job (at its partial folder), step them in lockstep, finish them;
    returns per job (``ReplayResult``, None) or (None, the one-line reason it failed).  The scene is
    restored once, at the end, as the first run found it."""
    frames = (plan.frames[0], plan.frames[1])
    engine_session = session.current()
    runs, opened, results = [], [], [None] * len(jobs)
    try:
        for index, job in enumerate(jobs):
            facts = {"lockstep_runs": len(jobs)}
            if plan_module.is_group_raster(job):  # said in its summary: the report never takes it for the raster run
                facts["group_raster"] = True
            try:
                runs.append(replay.ReplayRun(scene, camera, frames, job.mode, plan_module.partial_dir(folder, job),
                                             restores_scene=False, facts=facts, **run_arguments(plan, folder, job)))
                opened.append(index)
            except (camera_path.ReplayError, blender_process.UserError) as error:
                results[index] = (None, str(error).strip().splitlines()[0])
        received = []

        total = plan.frames[1] - plan.frames[0] + 1

        def switch(run):
            engine_session.replay = run.state  # the frame renderer this render uses

        def rounds_done(count):
            if on_frame is not None:
                on_frame(count, total, len(runs))

        with stop_on_signals(received):
            failed = step_in_lockstep(runs, switch, lambda: bool(received), after_round=rounds_done)
        if received:
            raise SweepInterrupted(received[0], jobs[opened[0]].id if opened else jobs[0].id,
                                   min((run.done for run in runs), default=0))
        # Finished in reverse order: numpy's BLAS threads come back as the first run found them.
        for position in reversed(range(len(runs))):
            run, index = runs[position], opened[position]
            if position in failed:
                results[index] = (None, _failure(run, failed[position]))
                close_run(run)  # a stopped render leaves its run open; a failed step closed it
                continue
            try:
                results[index] = (run.finish(), None)
            except Exception as error:  # summary.json could not be written (a full disk)
                results[index] = (None, _failure(run, error))
                close_run(run)
        return results
    except BaseException:
        for run in reversed(runs):
            close_run(run)
        for job in jobs:
            shutil.rmtree(plan_module.partial_dir(folder, job), ignore_errors=True)
        raise
    finally:
        engine_session.replay = None
        if runs:
            runs[0].restore_scene()


def close_run(run):
    """Close ``run`` if it is still open (its lock, renderer and GPU objects released), whatever
    else fails."""
    try:
        run.finish(cancelled=True)
    except Exception:  # already closed by its failed step, or summary.json unwritable: it is dropped
        pass


class LockstepExecutor:
    """``plan.LocalExecutor``'s order, except that the hybrid runs of each path run together
    (:func:`execute_group`) once the jobs they depend on are done; a run whose dependency failed is
    not run (status 'failed', saying which)."""

    def __init__(self, group=execute_group):
        self.group = group
        self.on_frame = None  # on_frame(done, total, runs) during a group (the sweep's progress line)

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
            if plan_module.in_lockstep_group(job):
                # The hybrid runs of this path (and its group's raster run) whose dependencies are
                # all handled, none failed.
                group = [other for other in order if other.id not in handled
                         and plan_module.in_lockstep_group(other) and plan.target(other) == plan.target(job)
                         and all(dependency in handled and dependency not in failed
                                 for dependency in other.depends_on)]
                begin = time.perf_counter()
                try:
                    results = self.group(str(plan_path), [other.id for other in group], self.on_frame)
                except Exception as error:  # the group's failure must not hide what the other jobs did
                    results = [plan_module.JobOutcome(other.id, "failed", time.perf_counter() - begin,
                                                      f"{type(error).__name__}: {error}") for other in group]
                for outcome in results:
                    record(outcome)
                for other in group:  # a group that said nothing of a run failed it
                    if other.id not in handled:
                        record(plan_module.JobOutcome(other.id, "failed", message="no outcome from its lockstep group"))
                continue
            begin = time.perf_counter()
            try:
                outcome = execute(str(plan_path), job.id)
            except Exception as error:
                outcome = plan_module.JobOutcome(job.id, "failed", time.perf_counter() - begin,
                                                 f"{type(error).__name__}: {error}")
            record(outcome)
        return outcomes
