"""Bad input, a full disk and interruptions, through the ``phrt`` command and the
``phrt.replay_path`` operator, as users meet them: a clear message, and what was rendered so far
stays valid - complete images under their final names (never a half-written one), CSV rows of
the finished frames, and a ``summary.json`` that says the run is partial.

The full disk is a file-size limit (RLIMIT_FSIZE) on the subprocess: Blender's image writer then
stops early without reporting an error, which PHRT must notice.  Each subprocess costs ~2 s of
``bpy`` import; they run up to three at a time in a module fixture."""
from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import bpy
import numpy as np
import pytest

from phrt import compat
from phrt.phrt_addon import schema
from phrt.phrt_addon.runs import run_files
from phrt.sample_scenes import showcase
from exr_passes import read_passes

PHRT = Path(sys.executable).with_name("phrt")
FRAMES = 40
PARALLEL = 3


def camera_path(scene, frames=FRAMES):
    camera = scene.camera
    camera.keyframe_insert("location", frame=1)
    camera.location.x -= 1.0
    camera.keyframe_insert("location", frame=frames)
    return camera


@pytest.fixture(scope="module")
def files(blender, tmp_path_factory):
    """path.blend (a 40-frame path at 64x48), odd.blend (objects of unsupported types and one
    without a material), one.blend (a path of one keyframe), and corrupt files."""
    folder = tmp_path_factory.mktemp("bad")
    scene = showcase.build_showcase(64, 48)
    scene.phrt.shadow_map_size = 256
    camera_path(scene)
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "path.blend"))
    data = (folder / "path.blend").read_bytes()
    (folder / "truncated.blend").write_bytes(data[: len(data) // 3])
    (folder / "garbage.blend").write_bytes(data[:12] + np.random.default_rng(0).bytes(40000))
    (folder / "empty.blend").write_bytes(b"")

    scene = showcase.build_showcase(64, 48)
    scene.phrt.shadow_map_size = 256
    camera_path(scene, 3)
    showcase.mesh_object("NoMaterial", showcase.cube(0.5), None, location=(0.8, -1.0, 0.25))
    for name, datablock in (("Hair", bpy.data.hair_curves.new("Hair")), ("Smoke", bpy.data.volumes.new("Smoke")),
                            ("Sketch", compat.new_grease_pencil("Sketch"))):
        scene.collection.objects.link(bpy.data.objects.new(name, datablock))
    curve = bpy.data.curves.new("Rope", "CURVE")
    curve.bevel_depth = 0.05
    spline = curve.splines.new("POLY")
    spline.points.add(1)
    spline.points[1].co = (1.0, 0.5, 0.5, 1.0)
    scene.collection.objects.link(bpy.data.objects.new("Rope", curve))
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "odd.blend"))

    scene = showcase.build_showcase(64, 48)
    scene.phrt.shadow_map_size = 256
    scene.camera.keyframe_insert("location", frame=7)
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "one.blend"))
    bpy.ops.wm.read_homefile(use_empty=True)
    # A folder PHRT cannot write to: a read-only tmpfs as root (root may write anywhere else), a
    # folder without write permission otherwise.
    read_only = folder / "read-only"
    read_only.mkdir()
    mounted = os.geteuid() == 0 and subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(read_only)], capture_output=True).returncode == 0
    if not mounted:
        read_only.chmod(0o555)
    yield folder
    if mounted:
        subprocess.run(["umount", "-l", str(read_only)], check=False)


def file_size_limit(limit):
    def apply():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def run_command(argv, cwd, limit=None):
    process = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=600,
                             preexec_fn=file_size_limit(limit) if limit else None)
    lines = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, lines


BATCH = ("import bpy, phrt; phrt.register(); bpy.ops.wm.open_mainfile(filepath={blend!r}); "
         "bpy.ops.phrt.replay_path(output_dir={out!r}, modes={{'HYBRID'}}{extra})")

# name: (argv after phrt or None for a batch script, file-size limit, expected status, message)
CASES = {
    "truncated": (["render", "{dir}/truncated.blend"], None, 2, "cannot open"),
    "garbage": (["render", "{dir}/garbage.blend"], None, 2, "cannot open"),
    "empty": (["render", "{dir}/empty.blend"], None, 2, "not a valid .blend"),
    "missing": (["render", "{dir}/nowhere.blend"], None, 2, "no such file"),
    "read_only_fs": (["render", "{dir}/path.blend", "--out", "{dir}/read-only/phrt-out"], None, 2, "cannot write"),
    "one_frame_path": (["render", "{dir}/one.blend", "--out", "run"], None, 0, None),
    "odd_objects": (["render", "{dir}/odd.blend", "--out", "run", "--mode", "raytrace"], None, 0, None),
    "disk_full_images": (["render", "{dir}/path.blend", "--out", "run", "--frames", "1-3"], 25000, 2,
                         "could not be written completely"),
    "disk_full_logs": (["render", "{dir}/path.blend", "--out", "run", "--images", "none"], 6000, 2,
                       "is the disk full?"),
    "operator_disk_full": (None, 25000, 1, "could not be written completely"),
    "operator_odd_objects": (None, None, 0, None),
}


@pytest.fixture(scope="module")
def runs(files):
    cases = files / "cases"
    jobs = {}
    for name, (args, limit, _, _) in CASES.items():
        cwd = cases / name
        cwd.mkdir(parents=True)
        if args is None:
            blend = files / ("odd.blend" if "odd" in name else "path.blend")
            extra = ", frame_start=1, frame_end=3" if "disk" in name else ""
            argv = [sys.executable, "-c", BATCH.format(blend=str(blend), out=str(cwd / "runs"), extra=extra)]
        else:
            argv = [str(PHRT)] + [arg.format(dir=files) for arg in args]
        jobs[name] = (argv, cwd, limit)
    with ThreadPoolExecutor(PARALLEL) as pool:
        futures = {name: pool.submit(run_command, *job) for name, job in jobs.items()}
        return {name: future.result() for name, future in futures.items()}


def run_dir_of(files, case):
    cwd = files / "cases" / case
    if (cwd / "run").exists():
        return cwd / "run"
    found = [path.parent for path in cwd.rglob(schema.FRAMES_CSV)]
    assert len(found) == 1, found
    return found[0]


def check_run_is_valid(run_dir, partial):
    """Every image under a final name is complete and readable, one per logged frame; no
    temporary file is left; summary.json says whether the run is partial."""
    frames = run_files.read_frames(run_dir)
    images = sorted((run_dir / schema.FRAMES_DIR).glob("*"))
    leftovers = [path.name for path in run_dir.rglob("*") if "partial" in path.name or ".tmp" in path.name
                 or path.name == ".phrt-lock"]
    assert leftovers == []
    logged = {row["frame"] for row in frames}
    for image in images:
        assert run_files.image_is_complete(image), image
        if image.suffix == ".exr":
            passes = read_passes(image)
            assert {"Combined", "Depth", "Normal", "PHRT Selected", "PHRT Candidate"} <= set(passes)
            assert all(np.all(np.isfinite(pixels)) for pixels in passes.values())
        assert int(image.stem) in logged
    summary = run_files.read_summary(run_dir)
    assert summary["partial"] is partial
    assert summary["frame_count"] == len(frames)
    for row in run_files.read_selection(run_dir):
        assert row["frame"] in logged
    return frames, images, summary


@pytest.mark.parametrize("case", sorted(name for name, spec in CASES.items() if spec[2] == 2))
def test_bad_input_exits_2_with_one_clear_line(files, runs, case):
    status, stdout, stderr = runs[case]
    assert status == 2, (stdout, stderr)
    assert len(stderr) == 1 and stderr[0].startswith("phrt: error: "), stderr
    assert CASES[case][3] in stderr[0], stderr
    assert "Traceback" not in stdout


@pytest.mark.parametrize("case", ["truncated", "garbage", "empty", "missing", "read_only_fs"])
def test_refused_input_writes_nothing(files, runs, case):
    assert list((files / "cases" / case).iterdir()) == []


def test_a_one_frame_path_renders_its_frame(files, runs):
    status, stdout, stderr = runs["one_frame_path"]
    assert status == 0 and stderr == [], stderr
    frames, images, summary = check_run_is_valid(files / "cases" / "one_frame_path" / "run", partial=False)
    assert [row["frame"] for row in frames] == [7] and [image.name for image in images] == ["0007.exr"]


def test_unsupported_objects_are_warned_about_once_with_their_count(files, runs):
    """Hair curves, a volume and a grease pencil are skipped (one warning each, not one per
    frame); a curve is converted; an object without material is drawn with the default one."""
    status, stdout, stderr = runs["odd_objects"]
    assert status == 0, stderr
    warnings = [line for line in stderr if line.startswith("phrt: warning: ")]
    assert warnings == stderr and len(warnings) == 3, stderr
    for kind in ("CURVES", "VOLUME", "GREASEPENCIL"):
        assert sum(kind in line for line in warnings) == 1
    assert all("(on all 3 frames)" in line for line in warnings), warnings
    frames, _, summary = check_run_is_valid(files / "cases" / "odd_objects" / "run", partial=False)
    assert len(frames) == 3
    assert sorted(item["frames"] for item in summary["problems"]) == [3, 3, 3]
    rows = run_files.read_selection(files / "cases" / "odd_objects" / "run")
    assert {"NoMaterial", "Rope"} <= {row["element"] for row in rows}


def test_the_operator_warns_once_too(files, runs):
    status, stdout, stderr = runs["operator_odd_objects"]
    assert status == 0, stderr
    text = stdout + "\n".join(stderr)
    for kind in ("CURVES", "VOLUME", "GREASEPENCIL"):
        assert text.count(f"Objects of type {kind}") == 2, text  # the first frame, and the count at the end
    assert text.count("(on all 3 frames)") == 3


def test_a_full_disk_while_writing_images_keeps_what_was_complete(files, runs):
    status, _, stderr = runs["disk_full_images"]
    run_dir = files / "cases" / "disk_full_images" / "run"
    frames, images, summary = check_run_is_valid(run_dir, partial=True)
    assert images == [] and frames == []  # the first image already did not fit: nothing half-written kept
    assert "could not be written completely" in summary["error"]


def test_a_full_disk_while_writing_logs_keeps_the_complete_rows(files, runs):
    run_dir = files / "cases" / "disk_full_logs" / "run"
    frames, _, summary = check_run_is_valid(run_dir, partial=True)
    assert 3 <= len(frames) < FRAMES
    assert [row["frame"] for row in frames] == list(range(1, len(frames) + 1))
    assert (run_dir / schema.SELECTION_CSV).stat().st_size <= 6000


def test_the_operator_reports_a_full_disk_and_keeps_a_partial_summary(files, runs):
    status, stdout, stderr = runs["operator_disk_full"]
    assert status == CASES["operator_disk_full"][2]  # 1: the operator's error ends the batch script
    assert "could not be written completely" in "\n".join(stderr)
    run_dir = run_dir_of(files, "operator_disk_full")
    check_run_is_valid(run_dir, partial=True)


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_a_signal_stops_the_replay_between_frames_and_keeps_everything_complete(files, runs, signal_name,
                                                                                 tmp_path):
    run_dir = tmp_path / "run"
    # At 960x720 the 40 frames take seconds: frames.csv's rows are read back once summary.json
    # commits them (at most once a second), and at the scene's own size a fast machine had
    # finished the replay by then (the process then ends 0, not interrupted).
    process = subprocess.Popen([str(PHRT), "render", str(files / "path.blend"), "--out", str(run_dir),
                                "--resolution", "960x720"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:
            if (run_dir / schema.FRAMES_CSV).exists() and len(run_files.read_frames(run_dir)) >= 2:
                break
            if process.poll() is not None:
                break
            time.sleep(0.05)
        assert process.poll() is None, "the replay ended before it could be interrupted"
        process.send_signal(getattr(signal, signal_name))
        stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    number = getattr(signal, signal_name)
    assert process.returncode == 128 + number, stderr
    lines = [line for line in stderr.splitlines() if line.strip() and "EGL" not in line]
    assert lines == [line for line in lines if line.startswith("phrt: ")]
    assert any(f"interrupted by {signal_name}" in line for line in lines), lines
    frames, images, summary = check_run_is_valid(run_dir, partial=True)
    assert 2 <= len(frames) < FRAMES
    assert [int(image.stem) for image in images] == [row["frame"] for row in frames]
    assert summary["frames_planned"] == FRAMES and not summary.get("error")


def test_a_signal_stops_the_whole_sweep_not_only_its_run(files, tmp_path):
    """SIGTERM during a sweep's first run stops the sweep (exit 128 + 15, one line saying how to
    resume); no later job starts (it went on with the next job, each signal cancelling one run)."""
    out = tmp_path / "sweep"
    process = subprocess.Popen([str(PHRT), "sweep", str(files / "path.blend"), "--out", str(out),
                                "--resolution", "960x720", "--budget-at", "0.5", "--variants", "measured"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and process.poll() is None:
            started = [folder for folder in out.glob(".*.partial-*") if (folder / schema.FRAMES_CSV).exists()]
            if started and len(run_files.read_frames(started[0])) >= 2:
                break
            time.sleep(0.05)
        assert process.poll() is None, "the sweep ended before it could be interrupted"
        process.send_signal(signal.SIGTERM)
        stdout, stderr = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 128 + signal.SIGTERM, stderr
    lines = [line for line in stderr.splitlines() if line.strip() and "EGL" not in line]
    assert any("sweep interrupted by SIGTERM during" in line and "resume" in line for line in lines), lines
    assert not any("failed" in line for line in lines), lines
    # Only the interrupted first run was started: no other job's folder, no report.
    started = [path.name for path in out.iterdir() if path.is_dir()]
    assert started == [], started
    assert "[2/" not in stdout + stderr


def test_the_operator_refuses_a_folder_it_cannot_create(files, tmp_path):
    """A read-only tmpfs as root (every permission check passes for root), a folder without write
    permission otherwise (the ``files`` fixture)."""
    bpy.ops.wm.open_mainfile(filepath=str(files / "path.blend"))
    try:
        with pytest.raises(RuntimeError, match="cannot write to output folder"):
            bpy.ops.phrt.replay_path(output_dir=str(files / "read-only" / "phrt-out"), frame_start=1, frame_end=2)
    finally:
        bpy.ops.wm.read_homefile(use_empty=True)
