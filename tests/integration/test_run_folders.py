"""Run folders that never lie, through the ``phrt`` command: one writer per folder, --overwrite to
replace another run, bounded inputs, and a full disk or an unwritable folder at every write
(summary.json, plan.json, the report) refused with exit 2 and one line.

The full disk is a small tmpfs mounted for the test (the tests run as root here; elsewhere those
cases are skipped), the unwritable folder a read-only tmpfs: real ENOSPC and EROFS from the
kernel, not a simulation."""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt.phrt_addon import schema  # noqa: E402
from phrt.phrt_addon.raster import gbuffer  # noqa: E402
from phrt.phrt_addon.runs import run_files  # noqa: E402
from phrt.sample_scenes import showcase  # noqa: E402

PHRT = Path(sys.executable).with_name("phrt")
SMALL = ["--resolution", "32x24"]


def run_phrt(args, cwd, timeout=600):
    process = subprocess.run([str(PHRT), *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)
    errors = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, errors


def assert_one_error_line(result, expected):
    status, stdout, errors = result
    assert status == 2 and len(errors) == 1, errors
    assert errors[0].startswith("phrt: error: ") and expected in errors[0], errors
    assert "Traceback" not in stdout


@pytest.fixture(scope="module")
def blend(tmp_path_factory):
    """A 60-frame camera path over the showcase, 32x24."""
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    folder = tmp_path_factory.mktemp("folders")
    scene = showcase.build_showcase(32, 24)
    scene.phrt.shadow_map_size = 256
    camera = scene.camera
    camera.keyframe_insert("location", frame=1)
    camera.location.x -= 1.0
    camera.keyframe_insert("location", frame=60)
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "path.blend"))
    bpy.ops.wm.read_homefile(use_empty=True)
    return folder / "path.blend"


@contextlib.contextmanager
def tmpfs(folder: Path, options: str):
    """A tmpfs mounted at ``folder`` for the block (root only)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    folder.mkdir(parents=True, exist_ok=True)
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(folder)], capture_output=True)
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {mounted.stderr.decode().strip()}")
    try:
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


def fill(folder: Path):
    """Fill a tmpfs to its last byte."""
    with open(folder / "filler", "wb") as handle:
        with contextlib.suppress(OSError):
            while True:
                handle.write(b"\0" * 65536)
                handle.flush()
    with contextlib.suppress(OSError), open(folder / "filler", "ab") as handle:
        while True:
            handle.write(b"\0")
            handle.flush()


def wait_for(condition, process, timeout_s=300):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        if process.poll() is not None:
            return False
        time.sleep(0.05)
    return False


def test_a_second_writer_is_refused_and_a_dead_writers_lock_is_taken_over(blend, tmp_path):
    out = tmp_path / "R"
    # A long replay (frames past the path's end hold its last pose): it is still writing when the
    # second command, a Blender start later, looks at the folder.
    first = subprocess.Popen([str(PHRT), "render", str(blend), "--out", str(out), "--images", "none",
                              "--frames", "1-100000", *SMALL], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        assert wait_for(lambda: (out / schema.SUMMARY_JSON).exists(), first), "the first render never started"
        assert_one_error_line(run_phrt(["render", str(blend), "--out", str(out), *SMALL, "--frames", "1-2"],
                                       tmp_path), f"is being written by process {first.pid}")
        first.send_signal(signal.SIGKILL)
        first.wait()
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    killed = run_files.read_summary(out)
    assert killed["partial"] is True
    assert_one_error_line(run_phrt(["render", str(blend), "--out", str(out), *SMALL, "--frames", "1-2"], tmp_path),
                          "holds another run")
    status, _, errors = run_phrt(["render", str(blend), "--out", str(out), *SMALL, "--frames", "1-2", "--overwrite"],
                                 tmp_path)
    assert status == 0, errors
    summary = run_files.read_summary(out)
    assert summary["partial"] is False and summary["frame_count"] == 2
    assert not (out / ".phrt-lock").exists()


def test_exr_then_images_none_needs_overwrite_and_then_reports_timing_only(blend, tmp_path):
    frames = ["--frames", "1-2", *SMALL]
    assert run_phrt(["render", str(blend), "--out", "reference", "--mode", "raytrace", *frames], tmp_path)[0] == 0
    assert run_phrt(["render", str(blend), "--out", "R", *frames], tmp_path)[0] == 0
    assert sorted(path.name for path in (tmp_path / "R" / "frames").iterdir()) == ["0001.exr", "0002.exr"]
    assert_one_error_line(run_phrt(["render", str(blend), "--out", "R", "--images", "none", *frames], tmp_path),
                          "holds another run")
    assert run_files.read_summary(tmp_path / "R")["images"] == "exr"  # the refused command changed nothing
    status, _, errors = run_phrt(["render", str(blend), "--out", "R", "--images", "none", "--overwrite", *frames],
                                 tmp_path)
    assert status == 0, errors
    assert list((tmp_path / "R" / "frames").iterdir()) == []  # the old run's images went first
    status, _, errors = run_phrt(["report", "reference", "R", "--out", "report"], tmp_path)
    assert status == 0, errors
    text = (tmp_path / "report" / "report.md").read_text()
    line = next(line for line in text.splitlines() if line.startswith("| R |") and "timing only" in line)
    assert "rendered with --images none" in line


def test_a_huge_frame_range_starts_at_once_and_stops_on_sigint(blend, tmp_path):
    """--frames 1-2000000000: the frames are iterated, never listed (a list would need 16 GB)."""
    out = tmp_path / "huge"
    process = subprocess.Popen([str(PHRT), "render", str(blend), "--out", str(out), "--images", "none",
                                "--frames", "1-2000000000", *SMALL], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                               text=True)
    try:
        assert wait_for(lambda: (out / schema.FRAMES_CSV).exists()
                        and (out / schema.FRAMES_CSV).read_text().count("\n") >= 3, process), process.stderr.read()
        process.send_signal(signal.SIGINT)
        process.wait(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 128 + signal.SIGINT
    summary = run_files.read_summary(out)
    assert summary["frames_planned"] == 2000000000 and summary["partial"] is True and summary["frame_count"] >= 2


def test_a_resolution_whose_gbuffer_does_not_fit_is_refused_before_the_first_frame(blend, tmp_path):
    available = gbuffer.memory_available_bytes()
    if available is None or gbuffer.gbuffer_bytes(16384, 16384) <= available:
        pytest.skip("this machine has the memory for a 16384x16384 G-buffer")
    result = run_phrt(["render", str(blend), "--out", "big", "--resolution", "16384x16384"], tmp_path)
    assert_one_error_line(result, "GiB for its G-buffer alone")
    assert "16384x16384" in result[2][0]
    assert not (tmp_path / "big").exists()
    assert_one_error_line(run_phrt(["sweep", str(blend), "--out", "bigsweep", "--resolution", "16384x16384"],
                                   tmp_path), "GiB for its G-buffer alone")
    assert not (tmp_path / "bigsweep").exists()


@pytest.mark.parametrize("budgets", [["--budget-at", "0.251,0.252"], ["--budgets", "100"]])
def test_duplicate_run_ids_exit_2_before_the_plan_is_written(blend, tmp_path, budgets):
    assert_one_error_line(run_phrt(["sweep", str(blend), "--out", "sw", *budgets, *SMALL], tmp_path),
                          "give the same run id")
    assert not (tmp_path / "sw").exists()


def test_a_full_disk_under_summary_json_exits_2_and_leaves_a_consistent_run(blend, tmp_path):
    """A tmpfs with 7 inodes: the mount, the run folder, its lock, frames/, summary.json and the
    two CSVs.  The first rewrite of summary.json (a new file under a temporary name) finds no
    inode left: ENOSPC, while the CSVs' appends go on fitting.  The run stops with one line and
    reads back as the summary last written says."""
    with tmpfs(tmp_path / "disk", "size=1m,nr_inodes=7") as disk:
        result = run_phrt(["render", str(blend), "--out", str(disk / "run"), "--images", "none", *SMALL], tmp_path)
        assert_one_error_line(result, "is the disk full?")
        assert "No space left on device" in result[2][0]
        summary = run_files.read_summary(disk / "run")
        assert summary["partial"] is True and summary["frame_count"] < 60
        assert summary["frame_count"] == len(run_files.read_frames(disk / "run"))
        assert (disk / "run" / schema.FRAMES_CSV).read_text().count("\n") > 1 + summary["frame_count"]
        assert not [path.name for path in (disk / "run").iterdir() if ".tmp-" in path.name]
        assert not (disk / "run" / ".phrt-lock").exists()


def test_a_full_disk_under_plan_json_exits_2(blend, tmp_path):
    with tmpfs(tmp_path / "disk", "size=64k") as disk:
        fill(disk)
        assert_one_error_line(run_phrt(["sweep", str(blend), "--out", str(disk / "sw"), "--frames", "1-2", *SMALL],
                                       tmp_path), "cannot write the plan")
        assert not (disk / "sw" / "plan.json").exists()


def test_a_full_disk_under_the_report_exits_2(blend, tmp_path):
    assert run_phrt(["render", str(blend), "--out", "ref", "--mode", "raytrace", "--frames", "1-2", *SMALL],
                    tmp_path)[0] == 0
    with tmpfs(tmp_path / "disk", "size=64k") as disk:
        fill(disk)
        assert_one_error_line(run_phrt(["report", "ref", "--out", str(disk / "report")], tmp_path),
                              "cannot write the report")
        assert not [path for path in (disk / "report").rglob("*") if ".tmp-" in path.name] \
            if (disk / "report").exists() else True


def test_an_unwritable_report_folder_exits_2(blend, tmp_path):
    assert run_phrt(["render", str(blend), "--out", "ref", "--mode", "raytrace", "--frames", "1-2", *SMALL],
                    tmp_path)[0] == 0
    with tmpfs(tmp_path / "ro", "ro,size=64k") as read_only:
        assert_one_error_line(run_phrt(["report", "ref", "--out", str(read_only / "report")], tmp_path),
                              "cannot write to output folder")


def test_a_cluster_dashboard_binds_this_machine_only():
    from phrt.phrt_addon.runs import executors
    assert executors.DEFAULT_DASHBOARD.startswith("127.0.0.1:")
    with executors.DaskExecutor(workers=1, dashboard_address="127.0.0.1:0") as executor:
        assert executor.dashboard_link.startswith("http://127.0.0.1:")
        assert executor.client.scheduler.address.startswith("tcp://127.0.0.1:")
        sockets = executor.cluster.scheduler.http_server._sockets.values()
        assert {sock.getsockname()[0] for sock in sockets} == {"127.0.0.1"}
