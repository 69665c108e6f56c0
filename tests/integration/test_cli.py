"""The ``phrt`` command (CONTRACT.md section 2) as users run it: subprocesses of
``.venv/bin/phrt`` on a small .blend saved from the showcase with a keyframed camera.

Each subprocess costs ~2 s of ``bpy`` import, so every command runs once, up to
three at a time, in module fixtures; the tests then check what each one did."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt.phrt_addon import schema
from phrt.phrt_addon.runs import run_files
from phrt.sample_scenes.showcase import add_camera, build_showcase  # noqa: E402

PHRT = Path(sys.executable).with_name("phrt")
PATH_FRAMES = 30
PARALLEL = 3


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """showcase.blend (camera 'Camera' keyframed over 1-30, a still camera 'Overview'),
    nocamera.blend, a text file named x.blend, notes.txt and a plain file to write 'under'."""
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    folder = tmp_path_factory.mktemp("cli")
    scene = build_showcase(160, 120)
    camera = scene.camera
    camera.keyframe_insert("location", frame=1)
    camera.location.x -= 1.5
    camera.keyframe_insert("location", frame=PATH_FRAMES)
    add_camera((0.0, -8.0, 6.0), (0.0, 0.0, 0.0), name="Overview")
    scene.camera = camera
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "showcase.blend"))
    for name in ("Camera", "Overview"):
        bpy.data.objects.remove(bpy.data.objects[name])
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "nocamera.blend"))
    bpy.ops.wm.read_homefile(use_empty=True)
    (folder / "x.blend").write_text("not a blend file\n")
    (folder / "notes.txt").write_text("hello\n")
    (folder / "somefile").write_text("")
    return folder


def run_phrt(args, cwd):
    """(exit status, stdout, stderr lines without Mesa's EGL noise) of ``phrt ARGS``."""
    return run_command([str(PHRT), *args], cwd)


def run_command(argv, cwd):
    process = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=300)
    lines = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, lines


def run_all(commands, cwd):
    for name in commands:
        (cwd / name).mkdir(parents=True)
    with ThreadPoolExecutor(PARALLEL) as pool:
        futures = {name: pool.submit(run_command, argv, cwd / name) for name, argv in commands.items()}
        return {name: future.result() for name, future in futures.items()}


# Every documented option, in as few runs as possible (run folder relative to each case's cwd).
GOOD = {
    "raytrace": ["render", "{blend}", "--path", "Camera", "--frames", "1-3", "--mode", "raytrace",
                 "--resolution", "128x96", "--out", "runs/rt"],
    "hybrid_whole_path": ["render", "{blend}", "--resolution", "128x96", "--budget-ms", "5"],
    "raster_png": ["render", "{blend}", "--path", "Overview", "--frames", "2-2", "--mode", "RASTER",
                   "--images", "png"],
    "no_images": ["render", "{blend}", "--frames", "30-30", "--images", "none", "--out", "runs/none"],
}
BAD = {
    "missing_file": (["render", "{dir}/missing.blend"], "missing.blend"),
    "text_named_blend": (["render", "{dir}/x.blend"], "not a valid .blend"),
    "not_a_blend": (["render", "{dir}/notes.txt"], "not a .blend file"),
    "unknown_path": (["render", "{blend}", "--path", "Nope"], "no camera path 'Nope'"),
    "reversed_frames": (["render", "{blend}", "--frames", "9-3"], "ends before it starts"),
    "malformed_frames": (["render", "{blend}", "--frames", "abc"], "malformed frame range"),
    "negative_budget": (["render", "{blend}", "--budget-ms", "-1"], "budget"),
    "zero_resolution": (["render", "{blend}", "--resolution", "0x0"], "resolution"),
    "out_under_a_file": (["render", "{blend}", "--out", "{dir}/somefile/x"], "somefile"),
    "no_camera": (["render", "{dir}/nocamera.blend"], "no camera"),
    "unknown_mode": (["render", "{blend}", "--mode", "pathtrace"], "unknown mode 'pathtrace'"),
}


# docs/batch.md: the operator from a script on a saved file, with the bpy module.
BATCH_SCRIPT = ("import bpy, phrt; phrt.register(); bpy.ops.wm.open_mainfile(filepath='{blend}'); "
                "bpy.ops.phrt.replay_path(frame_start=1, frame_end=2, modes={{'RASTER', 'RAYTRACE'}}, "
                "output_dir='//batch_runs', images='NONE'{extra})")


def _expand(args, folder):
    return [str(PHRT)] + [arg.format(blend=folder / "showcase.blend", dir=folder) for arg in args]


@pytest.fixture(scope="module")
def runs(files):
    commands = {name: _expand(args, files) for name, args in GOOD.items()}
    commands.update({name: _expand(args, files) for name, (args, _) in BAD.items()})
    blend = files / "showcase.blend"
    commands["batch_script"] = [sys.executable, "-c", BATCH_SCRIPT.format(blend=blend, extra="")]
    commands["batch_script_error"] = [sys.executable, "-c", BATCH_SCRIPT.format(blend=blend, extra=", path='Nope'")]
    return run_all(commands, files / "cases")


@pytest.fixture(scope="module")
def report(files, runs):
    cases = files / "cases"
    folder = cases / "report_case"
    folder.mkdir()
    result = run_phrt(["report", str(cases / "raytrace" / "runs" / "rt"),
                       str(cases / "hybrid_whole_path" / "out" / "showcase-Camera-hybrid"), "--out", "report"],
                      folder)
    return result, folder / "report"


def _frames_written(run_dir):
    return sorted(path.name for path in (run_dir / schema.FRAMES_DIR).iterdir())


def _check_succeeded(result):
    status, stdout, stderr = result
    assert status == 0, stderr
    assert stderr == []  # no progress on a non-terminal, no warnings
    assert len(stdout.strip().splitlines()) == 1 and stdout.startswith("phrt: ")


def test_render_path_frames_mode_resolution_out(files, runs):
    _check_succeeded(runs["raytrace"])
    run_dir = files / "cases" / "raytrace" / "runs" / "rt"
    frames = run_files.read_frames(run_dir)
    assert [row["frame"] for row in frames] == [1, 2, 3] and {row["mode"] for row in frames} == {"RAYTRACE"}
    summary = run_files.read_summary(run_dir)
    assert summary["path"] == "Camera" and summary["scene"] == "showcase" and summary["resolution"] == [128, 96]
    assert _frames_written(run_dir) == ["0001.exr", "0002.exr", "0003.exr"]
    assert not (files / "cases" / "raytrace" / "out").exists()


def test_render_defaults_to_the_whole_path_hybrid_and_out_folder(files, runs):
    _check_succeeded(runs["hybrid_whole_path"])
    run_dir = files / "cases" / "hybrid_whole_path" / "out" / "showcase-Camera-hybrid"
    frames = run_files.read_frames(run_dir)
    assert [row["frame"] for row in frames] == list(range(1, PATH_FRAMES + 1))
    assert {row["mode"] for row in frames} == {"HYBRID"} and {row["budget_ms"] for row in frames} == {5}
    summary = run_files.read_summary(run_dir)
    assert summary["budget_ms"] == 5 and summary["frame_count"] == PATH_FRAMES
    assert len(_frames_written(run_dir)) == PATH_FRAMES
    assert runs["hybrid_whole_path"][1].rstrip().endswith("-> out/showcase-Camera-hybrid")


def test_render_png_images_of_another_path_at_the_scene_resolution(files, runs):
    _check_succeeded(runs["raster_png"])
    run_dir = files / "cases" / "raster_png" / "out" / "showcase-Overview-raster"
    assert _frames_written(run_dir) == ["0002.png"]
    summary = run_files.read_summary(run_dir)
    assert summary["path"] == "Overview" and summary["resolution"] == [160, 120] and summary["mode"] == "RASTER"
    assert all(not row["selected"] for row in run_files.read_selection(run_dir))


def test_render_without_images_writes_logs_only(files, runs):
    _check_succeeded(runs["no_images"])
    run_dir = files / "cases" / "no_images" / "runs" / "none"
    assert _frames_written(run_dir) == []
    assert [row["frame"] for row in run_files.read_frames(run_dir)] == [30]
    assert json.loads((run_dir / schema.SUMMARY_JSON).read_text())["images"] == "none"


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_exits_2_with_one_line_and_writes_nothing(files, runs, case):
    status, stdout, stderr = runs[case]
    assert status == 2, (stdout, stderr)
    assert len(stderr) == 1 and stderr[0].startswith("phrt: error: "), stderr
    assert BAD[case][1] in stderr[0]
    assert "Traceback" not in stdout
    cwd = files / "cases" / case
    assert list(cwd.iterdir()) == []  # no out/ folder, nothing half-done
    assert not (files / "somefile").is_dir()


def test_report_on_a_raytrace_and_a_hybrid_run(report):
    (status, stdout, stderr), folder = report
    assert status == 0, stderr
    assert (folder / "report.md").is_file() and (folder / "report.html").is_file()
    markdown = (folder / "report.md").read_text()
    assert "hybrid" in markdown.lower() and "raytrace" in markdown.lower()
    assert "report.md" in stdout


def test_report_of_a_folder_that_is_not_a_run(files, runs):
    status, _, stderr = run_phrt(["report", str(files)], files)
    assert status == 2 and len(stderr) == 1 and stderr[0].startswith("phrt: error: ")


def test_batch_replay_of_docs_batch_md_writes_one_run_per_mode(files, runs):
    status, _, stderr = runs["batch_script"]
    assert status == 0, stderr
    for mode in ("raster", "raytrace"):
        run_dir = files / "batch_runs" / f"showcase-Camera-{mode}"
        assert [row["frame"] for row in run_files.read_frames(run_dir)] == [1, 2]
        assert run_files.read_summary(run_dir)["mode"] == mode.upper()
    assert runs["batch_script_error"][0] != 0  # a failing operator call fails the script
    assert "RuntimeError: Error: PHRT: no camera path 'Nope'" in "\n".join(runs["batch_script_error"][2])
