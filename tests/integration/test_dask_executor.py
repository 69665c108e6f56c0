"""The Dask executor's own rules on a real LocalCluster of 2 worker processes, with plain-Python
jobs (no Blender: the PHRT jobs are in test_dask_sweep.py): a job that raises is retried twice,
a job still failing then is reported with its one-line error, jobs depending on it are not run,
jobs run after what they depend on, and outcomes come back in plan order."""
import json
import os
import time
from pathlib import Path

import pytest

from phrt.phrt_addon.runs import executors, plan


def attempt_job(plan_path, job_id):
    """Records each attempt (pid, start, end) beside the plan; 'flaky' fails its first attempt,
    'broken' every one."""
    folder = Path(plan_path).parent
    log = folder / f"{job_id}.attempts"
    with open(log, "a") as handle:
        handle.write(json.dumps({"pid": os.getpid(), "start": time.time()}) + "\n")
    attempts = len(log.read_text().splitlines())
    if job_id == "broken":
        raise RuntimeError(f"broken for good (attempt {attempts})\nsecond line")
    if job_id == "flaky" and attempts == 1:
        raise OSError("lost the shared folder for a moment")
    time.sleep(0.2)
    return plan.JobOutcome(job_id, "done", 0.2, f"attempt {attempts}", worker="")


def test_retries_failures_and_dependencies_on_a_local_cluster(tmp_path):
    jobs = [plan.Job("steady", "run", "RASTER"), plan.Job("flaky", "run", "RASTER"),
            plan.Job("broken", "run", "RASTER"),
            plan.Job("after-broken", "run", "HYBRID", depends_on=["broken"]),
            plan.Job("after-flaky", "run", "HYBRID", depends_on=["flaky", "steady"])]
    built = plan.Plan("s", "s", "p", [1, 2], [8, 8], [], 8, jobs)
    plan_path = plan.write_plan(built, tmp_path)
    seen = []
    with executors.DaskExecutor(workers=2, dashboard_address=":0") as executor:
        assert executor.dashboard_link.startswith("http://")
        outcomes = executor.run(plan_path, built, attempt_job, on_outcome=seen.append)
    assert executor.worker_exits == []
    assert [outcome.job_id for outcome in outcomes] == [job.id for job in jobs]
    assert sorted(outcome.job_id for outcome in seen) == sorted(job.id for job in jobs)
    result = {outcome.job_id: outcome for outcome in outcomes}
    assert result["steady"].status == "done" and result["steady"].message == "attempt 1"
    assert result["flaky"].status == "done" and result["flaky"].message == "attempt 2"
    assert result["broken"].status == "failed"
    assert result["broken"].message == "RuntimeError: broken for good (attempt 3)"  # 1 + retries=2, one line
    assert result["after-broken"].status == "failed" and result["after-broken"].message == "not run: broken failed"
    assert not (tmp_path / "after-broken.attempts").exists()
    assert result["after-flaky"].status == "done"
    started = {name: [json.loads(line)["start"] for line in (tmp_path / f"{name}.attempts").read_text().splitlines()]
               for name in ("steady", "flaky", "after-flaky")}
    assert started["after-flaky"][0] > max(started["flaky"] + started["steady"])
    pids = {int(outcome.worker.rsplit(":", 1)[1]) for outcome in outcomes if outcome.worker}
    assert os.getpid() not in pids and pids  # the jobs ran in the worker processes


def test_a_cluster_whose_workers_do_not_see_the_plan_is_refused(tmp_path):
    built = plan.Plan("s", "s", "p", [1, 2], [8, 8], [], 8, [plan.Job("steady", "run", "RASTER")])
    plan.write_plan(built, tmp_path)
    with executors.DaskExecutor(workers=1, dashboard_address=":0") as executor:
        with pytest.raises(executors.ExecutorError, match="does not see .*elsewhere.json: the sweep folder"):
            executor.run(tmp_path / "elsewhere.json", built, attempt_job)
