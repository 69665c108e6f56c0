"""``phrt sweep --lockstep``: the hybrid runs of a path rendered together, frame by frame, so that
every budget and variant meets the machine in the same state.  Subprocesses of ``.venv/bin/phrt``
on the showcase with a keyframed camera (64x48, 4 frames, two budgets, two variants), then the
executor's order on a plan whose jobs are stand-ins (no rendering)."""
from __future__ import annotations

import csv
import json
import os
import shutil
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402,F401  (Blender first: the modules below import it)
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt.cli import lockstep  # noqa: E402
from phrt.phrt_addon import report  # noqa: E402
from phrt.phrt_addon.runs import plan as plan_module  # noqa: E402
from phrt.phrt_addon.runs import run_files  # noqa: E402
from phrt_render import job_lines, run_phrt, save_moving_showcase  # noqa: E402

SWEEP = ["--frames", "1-4", "--budget-at", "0.25,0.75", "--variants", "measured,benefit", "--resolution", "64x48",
         "--oracle-every", "2", "--lockstep", "--out", "sw"]
HYBRIDS = [f"showcase-Camera-hybrid-at{fraction}-{variant}" for fraction in ("0.25", "0.75")
           for variant in ("measured", "benefit")]
GROUP_RASTER = "showcase-Camera-raster-group"


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """(folder, first run of the sweep, the same command again, once more after a hybrid run was removed)."""
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    blend = save_moving_showcase(tmp_path_factory.mktemp("lockstep") / "showcase.blend", 64, 48)
    folder = blend.parent
    first = run_phrt(["sweep", str(blend), *SWEEP], folder)
    # The frames of the hybrid runs in the order they were written, before a run is redone below.
    written = sorted((path.stat().st_mtime_ns, int(path.stem)) for run in HYBRIDS
                     for path in (folder / "sw" / run / "frames").glob("*.exr"))
    first = first + ([frame for _, frame in written],)
    second = run_phrt(["sweep", str(blend), *SWEEP], folder)
    shutil.rmtree(folder / "sw" / HYBRIDS[1])
    third = run_phrt(["sweep", str(blend), *SWEEP], folder)
    return folder / "sw", first, second, third


def test_the_hybrid_runs_render_frame_by_frame_together(sweeps):
    folder, (status, stdout, errors, written), _, _ = sweeps
    assert status == 0, errors
    lines = job_lines(stdout)
    assert set(lines) == {"showcase-Camera-raster", "showcase-Camera-raytrace", *HYBRIDS, GROUP_RASTER, "oracle"}
    for run in HYBRIDS:
        assert lines[run].startswith("done") and "4 frames in lockstep with 4 other runs" in lines[run], lines[run]
        summary = run_files.read_summary(folder / run)
        assert summary["frame_count"] == 4 and summary["budget_source"]["method"] == "runs"
        assert summary["lockstep_runs"] == (1 if run == HYBRIDS[1] else 5)  # HYBRIDS[1]: redone alone below
    assert "4 frames in lockstep with 4 other runs" in lines[GROUP_RASTER]
    group = run_files.read_summary(folder / GROUP_RASTER)
    assert group["group_raster"] is True and group["lockstep_runs"] == 5 and group["mode"] == "RASTER"
    assert not list((folder / GROUP_RASTER).rglob("*.exr"))  # only its times are read: no images
    # Every run wrote frame f before any wrote frame f + 1: the images in the order they were written
    # go 1, 1, 1, 1, 2, 2... (one run after the other would go 1, 2, 3, 4, 1, 2...).
    assert written == [frame for frame in range(1, 5) for _ in HYBRIDS]
    assert not list(folder.glob(".*partial*"))
    with open(folder / "report" / "sweep.csv", newline="") as handle:
        rows = {row["run"]: row for row in csv.DictReader(handle)}
    for run in HYBRIDS:  # the drift against the raster run is reported, and the oracle judged each run
        assert float(rows[run]["speed_vs_raster"]) > 0 and int(rows[run]["judged_frames"]) == 2, rows[run]
        assert rows[run]["lockstep_runs"] == ("1" if run == HYBRIDS[1] else "5")
    assert rows["showcase-Camera-raster"]["lockstep_runs"] == "" and GROUP_RASTER not in rows


def test_the_oracles_shared_time_is_the_group_raster_runs(sweeps):
    """The budget's nominal time for tracing: budget minus the raster half and composite of the raster
    run rendered with the hybrid runs (the first raster run's only in a plain sweep)."""
    folder = sweeps[0]
    info = json.loads((folder / "oracle" / "oracle.json").read_text())
    assert info["shared_from"] == GROUP_RASTER
    # Its timings on the group's clock: its own G-buffer passes against the group raster run's.
    assert info["clock_frames"] >= 1 and 0.5 <= info["clock_ratio_min"] <= info["clock_ratio"] <= 2.0
    # Given to `phrt report` with the sweep's runs, it is never taken for the raster run.
    with pytest.raises(ValueError, match="group raster"):
        report.build_report([folder / GROUP_RASTER], out_dir=folder / "group-report")
    group = {row["frame"]: row for row in run_files.read_frames(folder / GROUP_RASTER)}
    first = {row["frame"]: row for row in run_files.read_frames(folder / "showcase-Camera-raster")}
    with open(folder / "oracle" / "regret.csv", newline="") as handle:
        regret = list(csv.DictReader(handle))
    steady = [row for row in regret if int(row["frame"]) > 1]
    assert steady
    for row in steady:
        frame = int(row["frame"])
        assert float(row["shared_ms"]) == pytest.approx(group[frame]["raster_ms"] + group[frame]["composite_ms"]
                                                        + group[frame]["select_ms"], rel=1e-4)
    # Two renders of one frame never take the same microseconds: the first run's would show here.
    assert any(abs(float(row["shared_ms"]) - first[int(row["frame"])]["raster_ms"] - first[int(row["frame"])]["select_ms"]
                   - first[int(row["frame"])]["composite_ms"]) > 1e-3 for row in steady)


def test_a_lockstep_sweep_run_again_skips_complete_runs_and_redoes_a_missing_one(sweeps):
    folder, _, (status, stdout, errors), (status_3, stdout_3, errors_3) = sweeps
    assert status == 0, errors
    assert {line.split()[0] for line in job_lines(stdout).values()} == {"skipped"}
    assert status_3 == 0, errors_3
    done = {job for job, line in job_lines(stdout_3).items() if line.startswith("done")}
    assert done == {HYBRIDS[1], "oracle"}  # alone in its group: the complete runs stay as they are
    assert "4 frames in lockstep with 0 other runs" in job_lines(stdout_3)[HYBRIDS[1]]
    assert run_files.read_summary(folder / HYBRIDS[1])["frame_count"] == 4
    assert run_files.read_summary(folder / HYBRIDS[1])["lockstep_runs"] == 1  # said, not hidden


def test_lockstep_with_workers_exits_2_with_one_line(tmp_path):
    status, _, errors = run_phrt(["sweep", "atrium", "--lockstep", "--workers", "2", "--out", "x"], tmp_path)
    assert status == 2 and len(errors) == 1 and "--lockstep" in errors[0] and "--workers" in errors[0]
    assert not (tmp_path / "x").exists()


def plan_of(targets=("path1",)):
    jobs = []
    for path in targets:
        raster, raytrace = f"s-{path}-raster", f"s-{path}-raytrace"
        jobs += [plan_module.Job(raster, "run", mode="RASTER", path=path),
                 plan_module.Job(raytrace, "run", mode="RAYTRACE", path=path)]
        jobs += [plan_module.Job(f"s-{path}-hybrid-{index}", "run", mode="HYBRID", budget_at=0.5, path=path,
                                 depends_on=[raster, raytrace]) for index in range(3)]
        jobs.append(plan_module.Job(f"{raster}-group", "run", mode="RASTER", variant=plan_module.GROUP_RASTER,
                                    path=path, depends_on=[raster, raytrace]))
    hybrids = [job.id for job in jobs if plan_module.in_lockstep_group(job)]  # each path's 3 hybrids, its group raster
    jobs.append(plan_module.Job("oracle", "oracle", depends_on=[job.id for job in jobs]))
    return plan_module.Plan(scene="s", scene_label="s", path=targets[0], frames=[1, 2], resolution=[8, 8],
                            budgets=[0.5], oracle_every=2, jobs=jobs), hybrids


def test_the_executor_runs_each_paths_hybrid_runs_as_one_group_after_their_references():
    plan, hybrids = plan_of(("path1", "path2"))
    calls = []

    def execute(_, job_id):
        calls.append(job_id)
        return plan_module.JobOutcome(job_id, "done")

    def group(_, job_ids, on_frame=None):
        calls.append(tuple(job_ids))
        on_frame(2, 2, len(job_ids))  # the group reports its rounds to the sweep's progress line
        return [plan_module.JobOutcome(job_id, "done") for job_id in job_ids]

    seen, frames = [], []
    executor = lockstep.LockstepExecutor(group)
    executor.on_frame = lambda done, total, runs: frames.append((done, total, runs))
    outcomes = executor.run("plan.json", plan, execute, on_outcome=seen.append)
    assert frames == [(2, 2, 4), (2, 2, 4)]
    assert calls == ["s-path1-raster", "s-path1-raytrace", tuple(hybrids[:4]),
                     "s-path2-raster", "s-path2-raytrace", tuple(hybrids[4:]), "oracle"]
    assert hybrids[3] == "s-path1-raster-group"  # the group's raster run renders with the hybrid runs
    assert [outcome.job_id for outcome in outcomes] == [outcome.job_id for outcome in seen]
    assert sorted(outcome.job_id for outcome in outcomes) == sorted(job.id for job in plan.jobs)


def test_a_failed_reference_or_group_fails_its_runs_and_the_rest_goes_on():
    plan, hybrids = plan_of(("path1", "path2"))

    def execute(_, job_id):
        return plan_module.JobOutcome(job_id, "failed" if job_id == "s-path1-raytrace" else "done", message="x")

    def group(_, job_ids, on_frame=None):
        raise RuntimeError("the GPU went away")

    outcomes = {outcome.job_id: outcome for outcome in lockstep.LockstepExecutor(group).run("p", plan, execute)}
    assert all(outcomes[run].status == "failed" and "s-path1-raytrace failed" in outcomes[run].message
               for run in hybrids[:4])
    assert all(outcomes[run].status == "failed" and "the GPU went away" in outcomes[run].message
               for run in hybrids[4:])
    assert outcomes["s-path2-raster"].status == "done" and outcomes["oracle"].status == "failed"


class StubRun:
    """A run of ``frames`` frames whose steps are logged; ``fail_at``: the frame whose step raises."""

    def __init__(self, name, frames, log, fail_at=None):
        self.name, self.remaining, self.log, self.fail_at, self.done = name, frames, log, fail_at, 0

    def step(self):
        frame = self.done + 1
        if frame == self.fail_at:
            raise RuntimeError(f"{self.name} broke at frame {frame}")
        self.log.append((self.name, frame))
        self.done, self.remaining = frame, self.remaining - 1


def test_lockstep_renders_each_frame_of_every_run_before_the_next_starting_with_the_next_run():
    log, switched, rounds = [], [], []
    runs = [StubRun(name, 3, log) for name in "abc"]
    assert lockstep.step_in_lockstep(runs, before_step=lambda run: switched.append(run.name),
                                     after_round=lambda count: rounds.append((count, len(log)))) == {}
    assert log == [("a", 1), ("b", 1), ("c", 1), ("b", 2), ("c", 2), ("a", 2), ("c", 3), ("a", 3), ("b", 3)]
    assert switched == [name for name, _ in log]  # each step's renderer switched in before it
    assert rounds == [(1, 3), (2, 6), (3, 9)]  # after each complete round


def test_a_run_that_fails_is_left_out_and_the_others_finish():
    log = []
    runs = [StubRun("a", 3, log), StubRun("b", 3, log, fail_at=2), StubRun("c", 3, log)]
    failed = lockstep.step_in_lockstep(runs)
    assert list(failed) == [1] and "broke at frame 2" in str(failed[1])
    assert [frame for name, frame in log if name == "a"] == [1, 2, 3] == [frame for name, frame in log if name == "c"]
    assert ("b", 2) not in log and ("b", 3) not in log


def test_a_signal_stops_the_group_between_two_steps():
    log = []
    runs = [StubRun(name, 5, log) for name in "ab"]
    lockstep.step_in_lockstep(runs, stopped=lambda: len(log) >= 3)
    assert log == [("a", 1), ("b", 1), ("b", 2)]
