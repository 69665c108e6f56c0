"""``phrt sweep`` and ``--budget-at`` as users run them: subprocesses of ``.venv/bin/phrt`` on
a small .blend (the showcase with a keyframed camera, 64x48 pixels, 3 frames).

The sweep runs once, then again (every job skipped), then once more after a run's
summary.json was deleted (that run redone, and the oracle, which judged the old run)."""
from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt.phrt_addon.runs import plan as plan_module  # noqa: E402
from phrt.phrt_addon.runs import run_files
from phrt_render import save_moving_showcase  # noqa: E402

PHRT = Path(sys.executable).with_name("phrt")
SWEEP = ["--frames", "1-3", "--budgets", "1", "--resolution", "64x48", "--oracle-every", "2"]


def run_phrt(args, cwd):
    process = subprocess.run([str(PHRT), *args], cwd=cwd, capture_output=True, text=True, timeout=600)
    errors = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, errors


@pytest.fixture(scope="module")
def blend(tmp_path_factory):
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    return save_moving_showcase(tmp_path_factory.mktemp("sweep") / "showcase.blend", 64, 48)


@pytest.fixture(scope="module")
def sweeps(blend):
    """(first, second, third) runs of the same sweep: (status, stdout, stderr lines)."""
    folder = blend.parent
    first = run_phrt(["sweep", str(blend), *SWEEP, "--out", "sw"], folder)
    second = run_phrt(["sweep", str(blend), *SWEEP, "--out", "sw"], folder)
    redo = folder / "sw" / "showcase-Camera-hybrid-at0.50-error"
    (redo / "summary.json").unlink()
    third = run_phrt(["sweep", str(blend), *SWEEP, "--out", "sw"], folder)
    return folder / "sw", first, second, third


def statuses(stdout):
    """{job id: status} from the sweep's progress lines."""
    found = {}
    for line in stdout.splitlines():
        if line.startswith("phrt: [") and "]" in line:
            job, status = line.split("] ", 1)[1].split(": ", 1)
            found[job] = status.split()[0]
    return found


def test_sweep_writes_plan_runs_oracle_and_report(sweeps):
    folder, (status, stdout, errors), _, _ = sweeps
    assert status == 0, errors
    plan = json.loads((folder / "plan.json").read_text())
    runs = [job["id"] for job in plan["jobs"] if job["kind"] == "run"]
    assert len(runs) == 2 + len(plan_module.VARIANTS) and plan["budgets"] == [0.5]
    assert set(statuses(stdout).values()) == {"done"} and len(statuses(stdout)) == len(plan["jobs"])
    for run in runs:
        summary = run_files.read_summary(folder / run)
        assert summary["frame_count"] == 3 and summary["resolution"] == [64, 48]
    hybrid = run_files.read_summary(folder / "showcase-Camera-hybrid-at0.50-measured")
    assert hybrid["budget_source"]["method"] == "runs" and hybrid["budget_at"] == 0.5
    assert not list(folder.glob(".*partial*"))  # every job renamed its folder when complete
    with open(folder / "report" / "sweep.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert [row["run"] for row in rows] == runs
    assert all(row["regret"] != "" for row in rows if row["mode"] == "HYBRID")
    for name in ("report.md", "report.html", "error_vs_time.png", "selection_quality.png", "sweep.json",
                 "regret.csv"):
        assert (folder / "report" / name).is_file(), name
    assert "report.md" in stdout


def test_a_sweep_run_again_skips_every_complete_job(sweeps):
    _, first, (status, stdout, errors), _ = sweeps
    assert status == 0, errors
    assert set(statuses(stdout).values()) == {"skipped"} and statuses(stdout).keys() == statuses(first[1]).keys()


def test_a_run_whose_summary_is_missing_is_redone_and_so_is_the_oracle(sweeps):
    folder, _, _, (status, stdout, errors) = sweeps
    assert status == 0, errors
    done = {job for job, state in statuses(stdout).items() if state == "done"}
    assert done == {"showcase-Camera-hybrid-at0.50-error", "oracle"}
    assert run_files.read_summary(folder / "showcase-Camera-hybrid-at0.50-error")["frame_count"] == 3


def test_render_budget_at_resolves_from_runs_beside_it_or_calibrates(blend, sweeps):
    folder = blend.parent
    shutil.rmtree(folder / "alone", ignore_errors=True)
    beside = run_phrt(["render", str(blend), "--frames", "1-3", "--resolution", "64x48", "--budget-at", "0.25",
                       "--out", "sw/extra-hybrid"], folder)
    alone = run_phrt(["render", str(blend), "--frames", "1-3", "--resolution", "64x48", "--budget-at", "0.25",
                      "--out", "alone/hybrid"], folder)
    assert beside[0] == 0 and alone[0] == 0, (beside[2], alone[2])
    from_runs = run_files.read_summary(folder / "sw" / "extra-hybrid")["budget_source"]
    calibrated = run_files.read_summary(folder / "alone" / "hybrid")["budget_source"]
    assert from_runs["method"] == "runs" and from_runs["raster_run"].endswith("showcase-Camera-raster")
    assert calibrated["method"] == "calibration" and calibrated["calibration_frames"] == [1, 2, 3]
    for source in (from_runs, calibrated):
        assert source["raytrace_ms"] > 0 and source["raster_ms"] > 0
        assert source["budget_ms"] == pytest.approx(source["raster_ms"] + 0.25 * (source["raytrace_ms"]
                                                                                  - source["raster_ms"]), rel=1e-4)
    assert "budget at 0.25 =" in alone[1]
    assert list((folder / "alone").iterdir()) == [folder / "alone" / "hybrid"]  # calibration left nothing


@pytest.mark.parametrize("args, expected", [
    (["render", "{blend}", "--budget-at", "1.5"], "--budget-at 1.5 is outside 0..1"),
    (["render", "{blend}", "--budget-ms", "5", "--budget-at", "0.5"], "both given"),
    (["sweep", "{blend}", "--budgets", "0"], "not a count"),
    (["sweep", "{blend}", "--budget-at", "0.2,x"], "--budget-at"),
    (["sweep", "{blend}", "--budgets", "2", "--budget-at", "0.5"], "both given"),
    (["sweep", "{blend}", "--variants", "measured,nope"], "unknown selection variant(s) nope"),
    (["sweep", "{blend}", "--path", "Nowhere", "--out", "never"], "no camera path 'Nowhere'"),
    (["sweep", "{blend}", "--frames", "3-1", "--out", "never"], "ends before it starts"),
])
def test_bad_sweep_and_budget_input_exits_2_with_one_line(blend, args, expected):
    status, stdout, errors = run_phrt([arg.replace("{blend}", str(blend)) for arg in args], blend.parent)
    assert status == 2 and len(errors) == 1, errors
    assert errors[0].startswith("phrt: error: ") and expected in errors[0]
    assert not (blend.parent / "never").exists()
