"""Sweep plans on a Dask LocalCluster of 2 worker processes, each importing bpy and registering
PHRT (cli/dask_worker.py), rendering a small .blend (the showcase, 64x48, a few frames) through the
real replay, Embree and EXR files:

- a 4-run plan gives the same run directories as the local executor (images and logs equal apart
  from timing columns), and running it again skips every run;
- a worker process killed in the middle of a run: the run is retried in another process and
  completes, no partial directory remains, the other workers exit cleanly;
- a plan with one bad run (a camera path the scene does not have): its one-line message is in the
  report, the job depending on it is not run, the others complete;
- ``phrt sweep --workers 2`` as users run it, and its bad options (exit 2, one line)."""
from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402
import OpenEXR  # noqa: E402
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt.cli import sweep as sweep_engine  # noqa: E402
from phrt.phrt_addon.runs import plan as plan_module  # noqa: E402
from phrt.phrt_addon import schema
from phrt.phrt_addon.runs import run_files
from phrt_render import save_moving_showcase  # noqa: E402

PHRT = Path(sys.executable).with_name("phrt")
RESOLUTION = [64, 48]


@pytest.fixture(scope="module")
def blend(tmp_path_factory):
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    return save_moving_showcase(tmp_path_factory.mktemp("dask") / "showcase.blend", *RESOLUTION)


@pytest.fixture(scope="module")
def cluster():
    with sweep_engine.make_executor(workers=2, dashboard_address=":0") as executor:
        yield executor


def a_plan(blend, jobs, frames=(1, 3)):
    return plan_module.Plan(scene=str(blend), scene_label="showcase", path="Camera", frames=list(frames),
                            resolution=RESOLUTION, budgets=[], oracle_every=8, jobs=jobs)


def four_runs(blend):
    """Raster, raytrace, and two hybrid runs after them at budgets whose selection does not depend
    on timing (everything affordable, nothing affordable): their logs must match run for run."""
    references = ["showcase-Camera-raster", "showcase-Camera-raytrace"]
    return a_plan(blend, [
        plan_module.Job(references[0], "run", "RASTER"),
        plan_module.Job(references[1], "run", "RAYTRACE"),
        plan_module.Job("showcase-Camera-hybrid-all", "run", "HYBRID", depends_on=references, budget_ms=100000.0),
        plan_module.Job("showcase-Camera-hybrid-none", "run", "HYBRID", depends_on=references, budget_ms=0.0),
    ])


def timing(name):
    return name.endswith(("_ms", "_over_budget"))  # p95_over_budget: a timing too


def read_csv(path):
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def assert_same_run(local, distributed):
    files = sorted(str(path.relative_to(local)) for path in local.rglob("*"))
    assert files == sorted(str(path.relative_to(distributed)) for path in distributed.rglob("*")), local.name
    for name in (schema.FRAMES_CSV, schema.SELECTION_CSV):
        rows, others = read_csv(local / name), read_csv(distributed / name)
        assert len(rows) == len(others) > 0 and rows[0].keys() == others[0].keys()
        for row, other in zip(rows, others):
            differ = {key for key in row if row[key] != other[key]}
            assert all(timing(key) for key in differ), (local.name, name, differ)
    summary, other = run_files.read_summary(local), run_files.read_summary(distributed)
    assert summary.keys() == other.keys()
    assert {key for key in summary if summary[key] != other[key] and not timing(key)} == set()
    for image in sorted((local / schema.FRAMES_DIR).glob("*.exr")):
        parts = OpenEXR.File(str(image)).parts
        other_parts = OpenEXR.File(str(distributed / schema.FRAMES_DIR / image.name)).parts
        assert [sorted(part.channels) for part in parts] == [sorted(part.channels) for part in other_parts]
        for part, other_part in zip(parts, other_parts):
            for channel in part.channels:
                assert np.array_equal(part.channels[channel].pixels, other_part.channels[channel].pixels), \
                    (local.name, image.name, channel)


def test_a_plan_on_two_dask_workers_gives_the_run_directories_of_the_local_executor(blend, cluster, tmp_path):
    built = four_runs(blend)
    local_plan = plan_module.write_plan(built, tmp_path / "local")
    local = plan_module.LocalExecutor().run(local_plan, built, sweep_engine.execute_job)
    dask_plan = plan_module.write_plan(built, tmp_path / "dask")
    distributed = cluster.run(dask_plan, built, sweep_engine.execute_job)
    assert [o.status for o in local] == [o.status for o in distributed] == ["done"] * 4, (local, distributed)
    assert all(outcome.worker for outcome in distributed) and not any(outcome.worker for outcome in local)
    workers = {int(outcome.worker.rsplit(":", 1)[1]) for outcome in distributed}
    assert os.getpid() not in workers
    for job in built.jobs:
        assert_same_run(tmp_path / "local" / job.id, tmp_path / "dask" / job.id)
    selected = {job.id: [int(row["n_selected"]) for row in read_csv(tmp_path / "dask" / job.id / "frames.csv")]
                for job in built.jobs}
    assert selected["showcase-Camera-hybrid-all"] == selected["showcase-Camera-raytrace"] != [0, 0, 0]
    assert selected["showcase-Camera-hybrid-none"] == selected["showcase-Camera-raster"] == [0, 0, 0]
    assert not list((tmp_path / "dask").glob(".*partial*"))
    again = cluster.run(dask_plan, built, sweep_engine.execute_job)
    assert [outcome.status for outcome in again] == ["skipped"] * 4


def test_a_plan_with_a_bad_run_reports_its_message_and_completes_the_others(blend, cluster, tmp_path):
    built = four_runs(blend)
    built.jobs[2:] = [plan_module.Job("showcase-Nowhere-raster", "run", "RASTER", path="Nowhere"),
                      plan_module.Job("showcase-Nowhere-hybrid", "run", "HYBRID", path="Nowhere",
                                      depends_on=["showcase-Nowhere-raster"])]
    plan_path = plan_module.write_plan(built, tmp_path)
    outcomes, files, no_report = sweep_engine.run_plan(plan_path, built, cluster)
    status = {outcome.job_id: outcome for outcome in outcomes}
    assert status["showcase-Camera-raster"].status == status["showcase-Camera-raytrace"].status == "done"
    bad = status["showcase-Nowhere-raster"]
    assert bad.status == "failed" and bad.message == ("no camera path 'Nowhere' in scene 'Scene'; its paths "
                                                       "are: Camera"), bad
    assert status["showcase-Nowhere-hybrid"].message == "not run: showcase-Nowhere-raster failed"
    assert no_report is None
    report = files.markdown.read_text()
    assert "## Failed jobs" in report
    assert f"| showcase-Nowhere-raster | {bad.message} |" in report
    assert "| showcase-Nowhere-hybrid | not run: showcase-Nowhere-raster failed |" in report
    assert "showcase-Nowhere" in files.html.read_text()
    rows = read_csv(files.sweep_csv)
    assert [row["run"] for row in rows] == ["showcase-Camera-raster", "showcase-Camera-raytrace"]
    assert not (tmp_path / "showcase-Nowhere-raster").exists() and not list(tmp_path.glob(".*partial*"))


def test_a_run_whose_worker_is_killed_is_retried_elsewhere_and_completes(blend, tmp_path):
    frames = (1, 12)
    built = a_plan(blend, [plan_module.Job("showcase-Camera-raytrace", "run", "RAYTRACE"),
                           plan_module.Job("showcase-Camera-raster", "run", "RASTER")], frames)
    plan_path = plan_module.write_plan(built, tmp_path)
    killed, stop = [], threading.Event()

    def kill_the_raytrace_run_once_it_writes():
        # A job's folder exists under its temporary name, .<id>.partial-<pid of the worker>, from
        # its replay's first frame until it is complete.
        while not stop.is_set() and not killed:
            for partial in tmp_path.glob(".showcase-Camera-raytrace.partial-*"):
                pid = int(partial.name.rsplit("-", 1)[1])
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
                break
            time.sleep(0.005)

    watcher = threading.Thread(target=kill_the_raytrace_run_once_it_writes, daemon=True)
    with sweep_engine.make_executor(workers=2, dashboard_address=":0") as executor:
        watcher.start()
        try:
            outcomes = executor.run(plan_path, built, sweep_engine.execute_job)
        finally:
            stop.set()
            watcher.join()
    assert len(killed) == 1, "the raytrace run was never seen writing"
    result = {outcome.job_id: outcome for outcome in outcomes}
    assert [outcome.status for outcome in outcomes] == ["done", "done"], outcomes
    assert int(result["showcase-Camera-raytrace"].worker.rsplit(":", 1)[1]) != killed[0]
    assert not list(tmp_path.glob(".*partial*"))
    run = tmp_path / "showcase-Camera-raytrace"
    assert plan_module.run_is_complete(run, built)
    assert len(read_csv(run / schema.FRAMES_CSV)) == 12
    assert sorted(path.name for path in (run / schema.FRAMES_DIR).iterdir()) == [f"{f:04d}.exr" for f in range(1, 13)]
    # The killed process is the only worker that did not exit with status 0 (the others, and the
    # one started in its place, import bpy and exit cleanly).
    assert executor.worker_exits == [(killed[0], "was killed by signal 9")]


def run_phrt(args, cwd):
    process = subprocess.run([str(PHRT), *args], cwd=cwd, capture_output=True, text=True, timeout=600)
    errors = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, errors


def test_sweep_with_workers_runs_the_plan_on_a_local_cluster(blend):
    status, stdout, errors = run_phrt(["sweep", str(blend), "--frames", "1-3", "--budgets", "1", "--variants",
                                       "measured", "--resolution", "64x48", "--oracle-every", "2", "--out", "swd",
                                       "--workers", "2"], blend.parent)
    assert status == 0 and errors == [], errors  # nothing from the workers but Mesa's EGL lines
    folder = blend.parent / "swd"
    assert "phrt: running on a Dask LocalCluster of 2 worker processes; dashboard http://" in stdout
    plan = json.loads((folder / "plan.json").read_text())
    done = [line for line in stdout.splitlines() if line.startswith("phrt: [") and ": done in " in line]
    assert len(done) == len(plan["jobs"]) == 4 and all(" on " in line for line in done)
    assert [row["run"] for row in read_csv(folder / "report" / "sweep.csv")] == \
        [job["id"] for job in plan["jobs"] if job["kind"] == "run"]
    assert (folder / "oracle" / "oracle.json").is_file() and not list(folder.glob(".*partial*"))
    # Not in lockstep: no group raster run; the oracle's shared time is the raster run's.
    assert json.loads((folder / "oracle" / "oracle.json").read_text())["shared_from"] == plan["jobs"][0]["id"]
    assert plan["jobs"][0]["id"].endswith("-raster")


@pytest.mark.parametrize("args, expected", [
    (["--workers", "2", "--scheduler", "tcp://127.0.0.1:8786"], "--workers and --scheduler both given"),
    (["--scheduler", "render1"], "malformed scheduler address 'render1'"),
    (["--scheduler", "tcp://127.0.0.1:9"], "cannot reach the Dask scheduler at tcp://127.0.0.1:9"),
    (["--workers", "0"], "0 is not a count"),
])
def test_bad_cluster_options_exit_2_with_one_line(blend, args, expected):
    status, _, errors = run_phrt(["sweep", str(blend), "--frames", "1-3", "--out", "never", *args], blend.parent)
    assert status == 2 and len(errors) == 1, errors
    assert errors[0].startswith("phrt: error: ") and expected in errors[0]
    assert not (blend.parent / "never").exists()
