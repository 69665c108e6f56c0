"""Blender version support (README "Blender versions"): the suite runs on every version of
the matrix (`make test-compat`); these tests pin what differs between them.

- Every process that registers PHRT ends with exit status 0: Blender 4.5 as a Python
  module hangs at exit while Python classes are still registered, so ``phrt.register()``
  arranges ``unregister()`` at interpreter exit (a user's script that registers and simply
  ends, the ``phrt`` command).
- ``phrt render`` prints only its own line on stdout, even when Blender logs its colour
  management at start-up (5.x, with the OCIO variable set; 5.2 sets it for its children).
- ``phrt.compat`` holds the differences (image format, node trees, .blend headers; the
  keyframe helpers are used by every sample scene test), and the manifest's minimum
  version and the README say what the matrix runs."""
from __future__ import annotations

import gzip
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")

import phrt  # noqa: E402
from phrt.cli import blender_process  # noqa: E402
from phrt import compat  # noqa: E402
from phrt.phrt_addon.runs import run_files
from phrt.sample_scenes.showcase import build_showcase  # noqa: E402

from exr_passes import read_passes  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PHRT = Path(sys.executable).with_name("phrt")
# A process that hangs at exit (Blender 4.5 with classes left registered) fails the test
# through this timeout instead of blocking the suite; no test measures time.
HANG_S = 240


@pytest.fixture(autouse=True)
def registered():
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    yield


def run(argv, cwd, env=None):
    """(exit status, stdout, stderr lines without Mesa's EGL noise); a hang fails the test."""
    try:
        process = subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=HANG_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{argv[:3]} did not end within {HANG_S} s (a hang at exit?)")
    lines = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, lines


def saved_scene(folder, name="scene.blend", compress=False):
    """A small showcase scene with a camera moving over frames 1-2, saved by this Blender."""
    scene = build_showcase(64, 48)
    camera = scene.camera
    camera.keyframe_insert("location", frame=1)
    camera.location.x -= 0.5
    camera.keyframe_insert("location", frame=2)
    path = Path(folder) / name
    bpy.ops.wm.save_as_mainfile(filepath=str(path), compress=compress)
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


def this_blenders_ocio_config():
    config = Path(bpy.utils.resource_path("LOCAL")) / "datafiles" / "colormanagement" / "config.ocio"
    assert config.is_file(), config
    return config


def test_script_that_registers_and_simply_ends_exits_0(tmp_path):
    status, stdout, stderr = run([sys.executable, "-c", "import bpy, phrt; phrt.register(); print('registered')"],
                                 tmp_path)
    assert status == 0, stderr[-20:]
    assert stdout.splitlines()[-1] == "registered"  # after what Blender logs at start-up


def test_phrt_render_exits_0_with_only_its_summary_on_stdout(tmp_path):
    blend = saved_scene(tmp_path)
    # With OCIO set, Blender 5.x logs 'color_management | Using OCIO=...' on stdout at start-up.
    env = dict(os.environ, OCIO=str(this_blenders_ocio_config()))
    status, stdout, stderr = run([str(PHRT), "render", str(blend), "--frames", "1-2", "--mode", "hybrid",
                                  "--out", "run"], tmp_path, env=env)
    assert status == 0, stderr[-20:]
    lines = stdout.splitlines()
    assert len(lines) == 1 and lines[0].startswith("phrt: scene/Camera hybrid: 2 frames"), stdout
    run_dir = tmp_path / "run"
    assert [row["frame"] for row in run_files.read_frames(run_dir)] == [1, 2]
    assert run_files.read_summary(run_dir)["blender_version"] == bpy.app.version_string
    passes = read_passes(run_dir / "frames" / "0002.exr")  # multilayer EXR on every version
    assert {"Combined", "Depth", "Normal", "PHRT Selected", "PHRT Candidate"} <= set(passes)
    assert passes["Combined"].shape == (48, 64, 4)


def test_bad_input_gets_one_line_on_stderr_even_when_blender_logs_at_start_up(tmp_path):
    env = dict(os.environ, OCIO=str(this_blenders_ocio_config()))
    status, stdout, stderr = run([str(PHRT), "render", str(tmp_path / "missing.blend")], tmp_path, env=env)
    assert status == 2 and stdout == ""
    assert len(stderr) == 1 and stderr[0].startswith("phrt: error: no such file"), stderr


def test_blend_saved_by_a_newer_blender_renders_with_a_warning_on_stderr(tmp_path):
    blend = saved_scene(tmp_path, "newer.blend")
    data = bytearray(blend.read_bytes())
    header = re.match(rb"BLENDER(?:[-_][vV](\d{3})|\d\d-\d\d[vV](\d{4}))", data)
    digits = 1 if header.group(1) else 2
    start = header.start(digits)
    major, minor = bpy.app.version[:2]
    newer = f"{major}{minor + 1:02d}" if digits == 1 else f"{major:02d}{minor + 1:02d}"
    data[start:start + len(newer)] = newer.encode()
    blend.write_bytes(bytes(data))
    assert compat.blend_file_version(blend) == (major, minor + 1)
    status, stdout, stderr = run([str(PHRT), "render", str(blend), "--frames", "1-1", "--images", "none",
                                  "--out", "run"], tmp_path)
    assert status == 0, stderr[-20:]
    assert len(stdout.splitlines()) == 1 and stdout.startswith("phrt: newer/Camera")
    warnings = [line for line in stderr if line.startswith("phrt: warning:")]
    assert len(warnings) == 1 and f"saved by Blender {major}.{minor + 1}, newer than this" in warnings[0], stderr


def test_blend_file_version_reads_every_kind_of_header(tmp_path):
    this_version = tuple(bpy.app.version[:2])
    assert compat.blend_file_version(saved_scene(tmp_path, "plain.blend")) == this_version
    assert compat.blend_file_version(saved_scene(tmp_path, "zstd.blend", compress=True)) == this_version
    headers = {b"BLENDER-v405REND": (4, 5), b"BLENDER_V293REND": (2, 93), b"BLENDER17-01v0502REND": (5, 2)}
    for number, (header, version) in enumerate(headers.items()):
        (tmp_path / f"{number}.blend").write_bytes(header + bytes(64))
        assert compat.blend_file_version(tmp_path / f"{number}.blend") == version
    (tmp_path / "old.blend").write_bytes(gzip.compress(b"BLENDER-v279REND" + bytes(64)))
    assert compat.blend_file_version(tmp_path / "old.blend") == (2, 79)
    (tmp_path / "text.blend").write_text("not a blend file, but long enough to be read\n")
    assert compat.blend_file_version(tmp_path / "text.blend") is None
    damaged = (tmp_path / "zstd.blend").read_bytes()[:4] + b"garbage" * 8
    (tmp_path / "damaged.blend").write_bytes(damaged)  # zstd magic, then no zstd stream
    assert compat.blend_file_version(tmp_path / "damaged.blend") is None
    (tmp_path / "damaged_gzip.blend").write_bytes(gzip.compress(b"BLENDER-v279REND" + bytes(64))[:12])
    assert compat.blend_file_version(tmp_path / "damaged_gzip.blend") is None


def test_sample_scene_saved_by_another_blender_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setattr(blender_process, "SAMPLE_DIR", tmp_path)  # no generator modules: only the version counts
    saved_scene(tmp_path, "arcade.blend", compress=True)
    assert not blender_process.sample_is_stale(tmp_path / "arcade.blend")
    major, minor = bpy.app.version[:2]
    other = b"BLENDER-v402" if (major, minor) != (4, 2) else b"BLENDER-v405"
    (tmp_path / "arcade.blend").write_bytes(other + b"REND" + bytes(64))
    assert blender_process.sample_is_stale(tmp_path / "arcade.blend")


def test_image_format_is_set_and_restored_on_this_version():
    bpy.ops.wm.read_homefile(use_empty=True)
    settings = bpy.context.scene.render.image_settings
    compat.set_image_format(settings, compat.PNG)
    settings.color_depth, settings.color_mode = "16", "RGB"
    state = compat.image_format_state(settings)
    compat.set_image_format(settings, compat.MULTILAYER_EXR)
    settings.color_depth = "32"
    assert settings.file_format != "PNG"
    compat.restore_image_format(settings, state)
    assert (settings.file_format, settings.color_depth, settings.color_mode) == ("PNG", "16", "RGB")
    with pytest.raises(ValueError, match="unknown image format 'TIFF'"):
        compat.set_image_format(settings, "TIFF")


def test_new_materials_and_worlds_get_the_node_tree_blender_renders_with():
    material = bpy.data.materials.new("CompatMaterial")
    tree = compat.ensure_node_tree(material)
    assert tree.nodes.get("Principled BSDF") is not None
    assert compat.node_tree_of(material) == tree
    world = bpy.data.worlds.new("CompatWorld")
    assert compat.ensure_node_tree(world).nodes.get("Background") is not None
    if bpy.app.version < (5, 0, 0):  # 4.5 can still render a material without its nodes
        material.use_nodes = False
        assert compat.node_tree_of(material) is None


def test_unregister_is_a_no_op_when_not_registered():
    phrt.unregister()
    try:
        assert not hasattr(bpy.types.Scene, "phrt")
        phrt.unregister()  # what Blender's own exit does after the exit hook ran: nothing left to do
    finally:
        phrt.register()
    assert hasattr(bpy.types.Scene, "phrt")


def test_failed_register_leaves_nothing_registered(monkeypatch):
    from phrt import panels
    phrt.unregister()

    def broken_register():
        raise RuntimeError("panels failed to register")
    monkeypatch.setattr(panels, "register", broken_register)
    with pytest.raises(RuntimeError, match="panels failed"):
        phrt.register()
    assert not hasattr(bpy.types.Scene, "phrt") and not hasattr(bpy.types.Object, "phrt")
    monkeypatch.undo()
    phrt.register()
    assert hasattr(bpy.types.Scene, "phrt")


def test_manifest_minimum_and_readme_say_what_the_matrix_runs():
    makefile = (ROOT / "Makefile").read_text()
    matrix = re.search(r"^COMPAT_MATRIX := (.+)$", makefile, re.MULTILINE).group(1).split()
    bpy_pins = dict(re.findall(r"^COMPAT_BPY_(\S+) := (\S+)$", makefile, re.MULTILINE))
    assert sorted(bpy_pins) == sorted(matrix)
    assert all(bpy_pins[version].startswith(version + ".") for version in matrix)
    assert re.search(r"^bpy==(\S+)$", (ROOT / "requirements.txt").read_text(), re.MULTILINE).group(1) in \
        bpy_pins.values()  # the default Blender of `make test` is in the matrix
    lowest = min(matrix, key=lambda version: tuple(map(int, version.split("."))))
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["blender_version_min"] == f"{lowest}.0"
    readme = (ROOT / "README.md").read_text()
    assert "make test-compat" in readme
    claim = re.search(r"^Tested on Blender (.+?) \(`make test-compat`\)", readme, re.MULTILINE)
    assert claim is not None, "README: the 'Tested on Blender ...' line is missing"
    assert re.findall(r"\b\d\.\d\b", claim.group(1)) == sorted(matrix, key=lambda v: tuple(map(int, v.split("."))))
    running = tuple(bpy.app.version[:2])
    assert running >= tuple(map(int, lowest.split(".")))
