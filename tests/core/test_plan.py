"""A sweep as a plan of jobs (phrt_addon/runs/plan.py) and budgets between the modes
(phrt_addon/select/mode_budgets.py).  No bpy: the jobs here are plain functions."""
import json

import pytest

from phrt.phrt_addon.select import mode_budgets
from phrt.phrt_addon.report import oracle
from phrt.phrt_addon.runs import plan
from phrt.phrt_addon.runs.run_log import RunLog


def test_budgets_are_spread_evenly_strictly_between_raster_and_raytrace():
    assert plan.budget_fractions(3) == [0.25, 0.5, 0.75]
    assert plan.budget_fractions(1) == [0.5]
    with pytest.raises(ValueError):
        plan.budget_fractions(0)


def sweep_plan(budgets=(0.25, 0.75)):
    return plan.build_plan("arcade", "arcade", "path1", (1, 24), (320, 240), budgets)


def test_plan_has_raster_and_raytrace_then_every_budget_in_every_variant_then_the_oracle():
    built = sweep_plan()
    ids = [job.id for job in built.jobs]
    assert ids[:2] == ["arcade-path1-raster", "arcade-path1-raytrace"]
    assert len(ids) == len(set(ids)) == 2 + 2 * len(plan.VARIANTS) + 1
    hybrids = [job for job in built.jobs if job.mode == "HYBRID"]
    assert {job.budget_at for job in hybrids} == {0.25, 0.75}
    assert {job.overrides["cost_mode"] for job in hybrids} == {"MEASURED", "PAPER"}  # both cost modes
    assert {job.overrides["selection_weight"] for job in hybrids} == {0.0, 0.1, 0.5}
    assert {job.overrides["relevance"] for job in hybrids} == {"PAPER", "ERROR"}
    assert {job.overrides["selection_order"] for job in hybrids} == {"RELEVANCE", "RELEVANCE_PER_MS"}
    assert all(job.depends_on == ids[:2] for job in hybrids)
    oracle_job = built.jobs[-1]
    assert oracle_job.kind == "oracle" and set(oracle_job.depends_on) == {ids[0], ids[1], *(job.id for job in hybrids)}


def test_a_lockstep_plan_renders_a_second_raster_run_in_the_group_for_the_oracle_not_the_report(tmp_path):
    built = plan.build_plan("arcade", "arcade", "path1", (1, 24), (320, 240), (0.25,), ("measured", "benefit"),
                            group_raster=True)
    group = built.job("arcade-path1-raster-group")
    assert group.mode == "RASTER" and plan.is_group_raster(group) and plan.in_lockstep_group(group)
    assert group.depends_on == ["arcade-path1-raster", "arcade-path1-raytrace"]  # after the budgets' references
    assert not plan.is_group_raster(built.job("arcade-path1-raster"))
    assert not plan.in_lockstep_group(built.job("arcade-path1-raster"))
    oracle_job = built.job(oracle.ORACLE_DIR)
    # Not a dependency of the oracle (its failure must not cost the oracle), but before it in the plan.
    assert group.id not in oracle_job.depends_on
    assert [job.id for job in built.in_dependency_order()].index(group.id) < len(built.jobs) - 1
    assert group not in built.reported_runs and len(built.reported_runs) == len(built.runs) - 1 == 4
    assert plan.run_images(group) == "none" and plan.run_images(built.job("arcade-path1-raster")) == "exr"
    assert plan.read_plan(plan.write_plan(built, tmp_path)).job(group.id) == group
    assert "arcade-path1-raster-group" not in [job.id for job in sweep_plan().jobs]  # a plain sweep: none
    # The oracle's shared time: from the group raster run once it is complete, else the first raster run.
    assert plan.shared_raster(built, tmp_path, oracle_job) == tmp_path / "arcade-path1-raster"
    finished_run(tmp_path / group.id, base_ms=30.0)
    assert plan.shared_raster(built, tmp_path, oracle_job) == tmp_path / group.id


def test_an_oracle_is_redone_when_the_raster_run_it_took_its_shared_time_from_changed(tmp_path):
    built = plan.build_plan("arcade", "arcade", "path1", (1, 24), (320, 240), (0.25,), ("measured",),
                            group_raster=True)
    oracle_job, group = built.job(oracle.ORACLE_DIR), built.job("arcade-path1-raster-group")
    hybrid = next(job for job in built.runs if job.mode == "HYBRID")
    finished_run(tmp_path / hybrid.id, mode="HYBRID")
    finished_run(tmp_path / group.id, base_ms=30.0)
    runs = {hybrid.id: tmp_path / hybrid.id}
    oracle.write_results(tmp_path / oracle.ORACLE_DIR, 4, [], [], [], runs, shared_dir=tmp_path / group.id)
    assert plan.job_is_complete(built, tmp_path, oracle_job)
    finished_run(tmp_path / group.id, base_ms=31.0)  # the group raster run redone: another summary
    assert not plan.job_is_complete(built, tmp_path, oracle_job)
    # An oracle written before the group raster run existed (shared from the first raster run) is redone too.
    oracle.write_results(tmp_path / oracle.ORACLE_DIR, 4, [], [], [], runs, shared_dir=tmp_path / "arcade-path1-raster")
    assert not plan.job_is_complete(built, tmp_path, oracle_job)
    oracle.write_results(tmp_path / oracle.ORACLE_DIR, 4, [], [], [], runs, shared_dir=tmp_path / group.id)
    assert plan.job_is_complete(built, tmp_path, oracle_job)


def test_plan_json_round_trips(tmp_path):
    built = sweep_plan()
    path = plan.write_plan(built, tmp_path / "sweep")
    assert path.name == "plan.json"
    data = json.loads(path.read_text())
    assert [job["id"] for job in data["jobs"]] == [job.id for job in built.jobs]
    again = plan.read_plan(path)
    assert again.to_json() == built.to_json()
    with pytest.raises(ValueError, match="outside"):
        plan.build_plan("arcade", "arcade", "path1", (1, 2), (64, 48), [1.5])


def finished_run(folder, frames=24, resolution=(320, 240), mode="RASTER", base_ms=100.0, **extra):
    log = RunLog(folder)
    for frame in range(1, frames + 1):
        log.add_frame({"frame": frame, "mode": mode, "total_ms": base_ms + frame, "raster_ms": 90.0,
                       "select_ms": 1.0, "trace_ms": 0.0, "composite_ms": 9.0, "budget_ms": 150.0,
                       "predicted_trace_ms": 0.0, "n_candidates": 0, "n_visible": 0, "n_selected": 0, "rays": 0,
                       "setup_ms": 40.0 if frame == 1 else 0.0})
    return log.close({"scene": "arcade", "path": "path1", "resolution": list(resolution),
                      "blender_version": "5.0.1", "embreex_version": "4.4.0.post1", **extra})


def test_a_run_is_complete_only_with_a_whole_uncancelled_summary(tmp_path):
    built = sweep_plan()
    assert not plan.run_is_complete(tmp_path / "none", built)
    finished_run(tmp_path / "whole")
    assert plan.run_is_complete(tmp_path / "whole", built)
    finished_run(tmp_path / "short", frames=3)
    finished_run(tmp_path / "cancelled", cancelled=True)
    finished_run(tmp_path / "small", resolution=(160, 120))
    for name in ("short", "cancelled", "small"):
        assert not plan.run_is_complete(tmp_path / name, built), name


def test_publish_replaces_an_incomplete_folder(tmp_path):
    final = tmp_path / "run"
    final.mkdir()
    (final / "stale.txt").write_text("old")
    partial = tmp_path / ".run.partial-1"
    partial.mkdir()
    (partial / "summary.json").write_text("{}")
    plan.publish(partial, final)
    assert (final / "summary.json").exists() and not (final / "stale.txt").exists() and not partial.exists()


def test_local_executor_runs_in_order_and_skips_what_depends_on_a_failure(tmp_path):
    built = plan.build_plan("arcade", "arcade", "path1", (1, 2), (64, 48), [0.5], variants=("measured", "error"))
    path = plan.write_plan(built, tmp_path)
    calls = []

    def execute(plan_path, job_id):
        calls.append(job_id)
        assert plan_path == str(path)
        if job_id.endswith("raytrace"):
            raise RuntimeError("no Embree")
        return plan.JobOutcome(job_id, "done")

    seen = []
    outcomes = plan.LocalExecutor().run(path, built, execute, on_outcome=seen.append)
    assert calls == ["arcade-path1-raster", "arcade-path1-raytrace"]
    status = {outcome.job_id: outcome.status for outcome in outcomes}
    assert status["arcade-path1-raster"] == "done"
    assert set(status.values()) == {"done", "failed"} and len(outcomes) == len(built.jobs) == len(seen)
    raytrace = next(o for o in outcomes if o.job_id.endswith("raytrace"))
    assert "RuntimeError: no Embree" in raytrace.message
    assert next(o for o in outcomes if o.job_id == "oracle").message.startswith("not run: arcade-path1-raytrace")


# -- budgets between the modes ------------------------------------------------------------------

def test_budget_is_the_fraction_of_the_way_from_raster_to_raytrace():
    assert mode_budgets.budget_between(0.0, 200.0, 600.0) == 200.0
    assert mode_budgets.budget_between(0.25, 200.0, 600.0) == 300.0
    assert mode_budgets.budget_between(1.0, 200.0, 600.0) == 600.0
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError):
            mode_budgets.budget_between(bad, 200.0, 600.0)


def test_steady_mean_leaves_out_one_time_setup():
    rows = [{"total_ms": 500.0, "setup_ms": 400.0}, {"total_ms": 110.0, "setup_ms": 10.0},
            {"total_ms": 100.0}, {"total_ms": None}]
    assert mode_budgets.steady_mean_ms(rows) == pytest.approx(100.0)
    assert mode_budgets.steady_mean_ms([]) is None


def test_reference_runs_are_found_by_scene_path_resolution_and_machine(tmp_path):
    summary = finished_run(tmp_path / "raster")
    raytrace = finished_run(tmp_path / "raytrace", mode="RAYTRACE", base_ms=300.0)
    finished_run(tmp_path / "raytrace-cancelled", mode="RAYTRACE", base_ms=900.0, frames=30, cancelled=True)
    cpu = summary["machine"]["cpu_model"]
    assert raytrace["machine"]["cpu_model"] == cpu
    found = mode_budgets.find_reference_runs([tmp_path], "arcade", "path1", (320, 240), cpu)
    assert found == (tmp_path / "raster", tmp_path / "raytrace")
    assert mode_budgets.find_reference_runs([tmp_path], "arcade", "path2", (320, 240), cpu) is None
    assert mode_budgets.find_reference_runs([tmp_path], "arcade", "path1", (640, 480), cpu) is None
    assert mode_budgets.find_reference_runs([tmp_path], "arcade", "path1", (320, 240), "another CPU") is None
    # Run folders may be given themselves.
    assert mode_budgets.find_reference_runs([tmp_path / "raster", tmp_path / "raytrace"], "arcade", "path1",
                                      (320, 240)) == found
    resolved = mode_budgets.from_runs(0.5, *found)
    # Steady means: frame 1's 40 ms of set-up left out.  Raster 112.5 - 40/24, raytrace 312.5 - 40/24.
    assert resolved.method == "runs"
    assert resolved.raster_ms == pytest.approx(112.5 - 40 / 24) and resolved.raytrace_ms == pytest.approx(312.5 - 40 / 24)
    assert resolved.budget_ms == pytest.approx((resolved.raster_ms + resolved.raytrace_ms) / 2)
    source = resolved.as_summary()
    assert source["budget_at"] == 0.5 and source["raster_run"].endswith("raster")


def test_calibration_frames_spread_over_the_range():
    assert mode_budgets.calibration_frames((1, 1000), 3) == [1, 500, 1000]
    assert mode_budgets.calibration_frames((5, 6), 3) == [5, 6]
    assert mode_budgets.calibration_frames((7, 7), 3) == [7]


def test_duplicate_run_ids_are_refused_before_a_plan_is_written(tmp_path):
    with pytest.raises(plan.PlanError, match="budgets 0.251 and 0.252 give the same run id"):
        plan.build_plan("arcade", "arcade", "path1", (1, 2), (64, 48), [0.251, 0.252])
    with pytest.raises(plan.PlanError, match="same run id"):
        plan.build_plan("arcade", "arcade", "path1", (1, 2), (64, 48), plan.budget_fractions(100))
    assert len(plan.build_plan("arcade", "arcade", "path1", (1, 2), (64, 48), plan.budget_fractions(98)).runs) \
        == 2 + 98 * len(plan.VARIANTS)


@pytest.mark.parametrize("job_id", ["../..", "..", ".", "a/b", "a\\b", ".hidden", "", "tab\tname", 3])
def test_a_plan_whose_job_id_is_not_a_plain_name_is_refused_when_read(tmp_path, job_id):
    """A tampered plan.json cannot make a job write or remove outside the sweep folder."""
    sweep = tmp_path / "sweep"
    outside = tmp_path / "precious"
    outside.mkdir()
    (outside / "keep.txt").write_text("mine")
    path = plan.write_plan(sweep_plan(), sweep)
    data = json.loads(path.read_text())
    data["jobs"][0]["id"] = job_id
    path.write_text(json.dumps(data))
    with pytest.raises(plan.PlanError, match="not a plain folder name"):
        plan.read_plan(path)
    assert (outside / "keep.txt").read_text() == "mine"


def test_a_camera_whose_name_is_not_a_folder_name_is_refused_when_the_plan_is_built():
    with pytest.raises(plan.PlanError, match="not a plain folder name"):
        plan.build_plan("arcade", "arcade", "cam/1", (1, 2), (64, 48), [0.5])


def test_nothing_outside_the_sweep_folder_is_removed(tmp_path):
    (tmp_path / "sweep").mkdir()
    with pytest.raises(plan.PlanError, match="not inside"):
        plan.inside(tmp_path / "sweep", tmp_path / "sweep" / ".." / "other")
    with pytest.raises(plan.PlanError):
        plan.inside(tmp_path / "sweep", tmp_path / "sweep")
    assert plan.inside(tmp_path / "sweep", tmp_path / "sweep" / "run") == tmp_path / "sweep" / "run"


def test_a_run_is_redone_when_its_recorded_work_differs(tmp_path):
    from phrt.phrt_addon.runs import work
    built = sweep_plan()
    job = built.runs[0]
    blend = tmp_path / "scene.blend"
    blend.write_bytes(b"BLENDER-v500 one")
    wanted = plan.wanted_work(built, job, blend)
    finished_run(tmp_path / "run", work=wanted)
    assert plan.run_redo_reason(tmp_path / "run", built, wanted) is None
    other_frames = plan.build_plan("arcade", "arcade", "path1", (25, 48), (320, 240), (0.25, 0.75))
    assert plan.run_redo_reason(tmp_path / "run", other_frames, plan.wanted_work(other_frames, job, blend)) \
        == "frames 1-24 -> 25-48"
    blend.write_bytes(b"BLENDER-v500 two")
    assert plan.run_redo_reason(tmp_path / "run", built, plan.wanted_work(built, job, blend)) \
        == "the scene file changed"
    hybrid = built.runs[2]
    changed = plan.wanted_work(built, hybrid, blend)
    assert "settings changed" in work.work_difference({**changed, "settings": {**changed["settings"],
                                                                              "budget_at": 0.5}}, changed)
    finished_run(tmp_path / "old")  # a run of an older PHRT: no record
    assert plan.run_redo_reason(tmp_path / "old", built, wanted) == "the run has no record of its work"


def test_only_dead_attempts_are_cleaned_up(tmp_path):
    import subprocess
    import sys
    from phrt.phrt_addon.runs import lock
    built = sweep_plan()
    job = built.runs[0]
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        names = {"dead": f".{job.id}.partial-{lock.owner_tag(gone.pid)}",
                 "live": f".{job.id}.partial-{lock.owner_tag(live.pid)}",
                 "elsewhere": f".{job.id}.partial-otherhost-{gone.pid}",
                 "mine": plan.partial_dir(tmp_path, job).name}
        for name in names.values():
            (tmp_path / name).mkdir()
        assert sorted(path.name for path in plan.dead_attempts(tmp_path, job)) == sorted(
            [names["dead"], names["mine"]])
    finally:
        live.kill()
        live.wait()
