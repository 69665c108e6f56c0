"""The parts of running a plan that need neither Blender nor a cluster (phrt_addon/runs/executors.py,
phrt_addon/runs/plan.py): the Dask task's dependency rule, the executor options, the progress line,
jobs with their own scene and path, and dependency order."""
import io
import json

import pytest

from phrt.phrt_addon.runs import executors, plan
from phrt.phrt_addon.runs import progress as run_progress


def test_a_task_whose_dependency_failed_does_not_run_its_job():
    calls = []

    def execute(plan_path, job_id):
        calls.append((plan_path, job_id))
        return plan.JobOutcome(job_id, "done", 1.5, "3 frames\nand more")

    ok = plan.JobOutcome("raster", "done")
    bad = plan.JobOutcome("raytrace", "failed", message="no camera path 'X'")
    outcome = executors.run_job(execute, "/shared/plan.json", "hybrid", ok, bad)
    assert calls == [] and outcome.status == "failed" and outcome.message == "not run: raytrace failed"
    outcome = executors.run_job(execute, "/shared/plan.json", "hybrid", ok)
    assert calls == [("/shared/plan.json", "hybrid")]
    assert outcome.status == "done" and outcome.message == "3 frames"  # one line
    host, pid = outcome.worker.rsplit(":", 1)
    assert host and int(pid) > 0


def test_a_job_error_propagates_so_that_dask_retries_it():
    def execute(plan_path, job_id):
        raise OSError("disk full")

    with pytest.raises(OSError):
        executors.run_job(execute, "/shared/plan.json", "raster")


@pytest.mark.parametrize("address", ["tcp://render1:8786", "render1:8786", "tcp://10.0.0.7:8786",
                                     "tls://node-3.farm.local:8786", "tcp://[::1]:8786"])
def test_scheduler_addresses_that_dask_takes(address):
    assert executors.check_scheduler_address(address) == address


@pytest.mark.parametrize("address", ["", "render1", "http://render1:8786", "tcp://render1", "tcp://:8786",
                                     "tcp://render1:port"])
def test_malformed_scheduler_addresses_are_refused(address):
    with pytest.raises(executors.ExecutorError, match="malformed scheduler address"):
        executors.check_scheduler_address(address)


def test_executor_options():
    assert isinstance(executors.make_executor(), plan.LocalExecutor)
    assert isinstance(executors.make_executor(workers=2), executors.DaskExecutor)  # not started: nothing runs
    with pytest.raises(executors.ExecutorError, match="both given"):
        executors.make_executor(workers=2, scheduler="tcp://render1:8786")
    with pytest.raises(executors.ExecutorError, match="at least 1 worker"):
        executors.DaskExecutor(workers=0)


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_progress_shows_jobs_done_and_an_eta_from_the_jobs_that_ran():
    now = [100.0]
    stream = Terminal()
    progress = run_progress.Progress(5, stream, clock=lambda: now[0])
    assert progress.line() == "jobs 0/5 done (0 skipped, 0 failed), ETA --"
    progress.update(plan.JobOutcome("a", "skipped"))
    assert progress.eta_s() is None  # a skipped job says nothing about how long the others take
    now[0] = 120.0
    progress.update(plan.JobOutcome("b", "done", 20.0))
    assert progress.eta_s() == pytest.approx(20.0 * 3)
    now[0] = 130.0
    progress.update(plan.JobOutcome("c", "failed", message="x"))
    assert progress.line() == "jobs 3/5 done (1 skipped, 1 failed), ETA 30 s"  # 30 s over 2 jobs, 2 left
    progress.clear()
    assert stream.getvalue().endswith("\r\033[K")
    now[0] = 140.0
    progress.update(plan.JobOutcome("d", "done"))
    progress.update(plan.JobOutcome("e", "done"))
    assert stream.getvalue().endswith("jobs 5/5 done (1 skipped, 1 failed)\n")


def test_progress_shows_what_the_jobs_under_way_have_done_until_the_next_outcome():
    stream = Terminal()
    progress = run_progress.Progress(3, stream, clock=lambda: 0.0)
    progress.under_way("9 runs in lockstep, frame 40/200")
    assert stream.getvalue().endswith("jobs 0/3 done (0 skipped, 0 failed), ETA --; 9 runs in lockstep, frame 40/200")
    progress.update(plan.JobOutcome("a", "done"))
    assert "lockstep" not in progress.line()


def test_progress_is_silent_when_stderr_is_not_a_terminal():
    stream = io.StringIO()
    progress = run_progress.Progress(2, stream)
    progress.update(plan.JobOutcome("a", "done"))
    progress.clear()
    assert stream.getvalue() == ""


def test_a_job_may_replay_its_own_scene_and_path(tmp_path):
    built = plan.build_plan("arcade", "arcade", "path1", (1, 2), (64, 48), [0.5], variants=("measured",))
    built.jobs.append(plan.Job("atrium-path2-raster", "run", "RASTER", scene="atrium", path="path2"))
    built.jobs.append(plan.Job("mine-Cam-raster", "run", "RASTER", scene="/levels/mine.blend", path="Cam"))
    again = plan.read_plan(plan.write_plan(built, tmp_path))
    assert again.target(again.job("arcade-path1-raster")) == ("arcade", "arcade", "path1")
    assert again.target(again.job("atrium-path2-raster")) == ("atrium", "atrium", "path2")
    assert again.target(again.job("mine-Cam-raster")) == ("/levels/mine.blend", "mine", "Cam")
    # plan.json of before jobs had their own scene and path still reads
    data = json.loads((tmp_path / "plan.json").read_text())
    for job in data["jobs"]:
        for key in ("scene", "scene_label", "path"):
            job.pop(key)
    assert plan.Plan.from_json(data).target(built.jobs[0]) == ("arcade", "arcade", "path1")


def test_jobs_come_after_what_they_depend_on():
    jobs = [plan.Job("hybrid", "run", "HYBRID", depends_on=["raster", "raytrace"]),
            plan.Job("oracle", "oracle", depends_on=["hybrid"]),
            plan.Job("raster", "run", "RASTER"), plan.Job("raytrace", "run", "RAYTRACE")]
    built = plan.Plan("s", "s", "p", [1, 2], [8, 8], [], 8, jobs)
    assert [job.id for job in built.in_dependency_order()] == ["raster", "raytrace", "hybrid", "oracle"]
    built.jobs.append(plan.Job("lost", "run", "RASTER", depends_on=["nowhere"]))
    with pytest.raises(ValueError, match="unknown job"):
        built.in_dependency_order()
    built.jobs[-1] = plan.Job("a", "run", "RASTER", depends_on=["b"])
    built.jobs.append(plan.Job("b", "run", "RASTER", depends_on=["a"]))
    with pytest.raises(ValueError, match="depend on each other"):
        built.in_dependency_order()


def test_the_papers_other_paths_are_one_plan_of_runs_named_as_phrt_render_names_them():
    from phrt.cli import paper
    others = paper.other_paths_plan([1, 1000], [640, 480])
    ids = [job.id for job in others.jobs]
    assert len(ids) == len(set(ids)) == 2 * 2 * 3
    assert ids[:3] == ["arcade-path2-raster", "arcade-path2-raytrace", "arcade-path2-hybrid"]
    for job in others.jobs:
        scene, label, path = others.target(job)
        assert path != paper.SWEPT_PATH and job.id == f"{label}-{path}-{job.mode.lower()}"
        if job.mode == "HYBRID":  # at the scene's own budget, resolved from its raster and raytrace runs
            assert job.budget_at is None and job.depends_on == [f"{label}-{path}-raster", f"{label}-{path}-raytrace"]
            assert job.overrides["selection"] == "PAPER"  # the paper's heuristic, not the sample scenes' BENEFIT
    assert [job.id for job in others.in_dependency_order()] == ids
