"""A sweep run again redoes every run whose recorded work differs (frames, the .blend's content)
and says why in one line; it skips a run only when the work is the same.  Subprocesses of
``.venv/bin/phrt`` on the showcase with a keyframed camera, 64x48, one budget, one variant."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt.phrt_addon.runs import run_files  # noqa: E402
from phrt_render import job_lines, run_phrt, save_moving_showcase  # noqa: E402

SWEEP = ["--budgets", "1", "--variants", "measured", "--resolution", "64x48", "--oracle-every", "3", "--out", "sw"]
RUNS = ("showcase-Camera-raster", "showcase-Camera-raytrace", "showcase-Camera-hybrid-at0.50-measured")


def edit_blend(path: Path):
    """Move the showcase's first mesh and save the file again (same name, other content)."""
    bpy.ops.wm.open_mainfile(filepath=str(path), use_scripts=False)
    mesh = next(obj for obj in bpy.context.scene.objects if obj.type == "MESH")
    mesh.location.z += 0.25
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)


def set_budget_fraction(path: Path, fraction: float):
    """Give the scene a Budget fraction of its own (the sample scenes have 0.4) and save it."""
    bpy.ops.wm.open_mainfile(filepath=str(path), use_scripts=False)
    bpy.context.scene.phrt.use_budget_at = True
    bpy.context.scene.phrt.budget_at = fraction
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    folder = tmp_path_factory.mktemp("redo")
    blend = save_moving_showcase(folder / "showcase.blend", 64, 48)
    set_budget_fraction(blend, 0.4)  # as the sample scenes: the raster and ray traced runs have none
    results = {"first": run_phrt(["sweep", str(blend), "--frames", "1-3", *SWEEP], folder),
               "other_frames": run_phrt(["sweep", str(blend), "--frames", "4-6", *SWEEP], folder),
               "unchanged": run_phrt(["sweep", str(blend), "--frames", "4-6", *SWEEP], folder)}
    edit_blend(blend)
    results["edited"] = run_phrt(["sweep", str(blend), "--frames", "4-6", *SWEEP], folder)
    return folder / "sw", results


def test_the_first_sweep_does_every_job(sweeps):
    _, results = sweeps
    status, stdout, errors = results["first"]
    assert status == 0, errors
    lines = job_lines(stdout)
    assert set(lines) == {*RUNS, "oracle"} and all(line.startswith("done") for line in lines.values()), lines


def test_another_frame_range_redoes_every_run_and_says_why(sweeps):
    folder, results = sweeps
    status, stdout, errors = results["other_frames"]
    assert status == 0, errors
    lines = job_lines(stdout)
    for run in RUNS:
        assert lines[run].startswith("done") and "redone: frames 1-3 -> 4-6" in lines[run], lines[run]
    assert lines["oracle"].startswith("done")
    assert [row["frame"] for row in run_files.read_frames(folder / RUNS[0])] == [4, 5, 6]


def test_the_same_work_again_is_skipped(sweeps):
    _, results = sweeps
    status, stdout, errors = results["unchanged"]
    assert status == 0, errors
    assert all(line.startswith("skipped") for line in job_lines(stdout).values()), stdout


def test_an_edited_blend_redoes_every_run_and_says_why(sweeps):
    _, results = sweeps
    status, stdout, errors = results["edited"]
    assert status == 0, errors
    lines = job_lines(stdout)
    for run in RUNS:
        assert lines[run].startswith("done") and "redone: the scene file changed" in lines[run], lines[run]
