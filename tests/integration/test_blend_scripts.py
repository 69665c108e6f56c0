"""A .blend's scripts never run when PHRT opens it: a registered text block (``use_module``, run
when a file is loaded with scripts allowed) and a scripted driver (run when the depsgraph is
evaluated) each touch a marker file.  Opened with scripts allowed (the control), both markers
appear; ``phrt render`` with the user preference set to auto-run scripts touches neither and warns
once that the scripts were not run."""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-user-"))

import bpy  # noqa: E402
import pytest  # noqa: E402

import phrt  # noqa: E402
from phrt.sample_scenes.showcase import build_showcase  # noqa: E402


def _touch(marker: Path) -> str:
    return f"__import__('pathlib').Path({str(marker)!r}).touch()"


@pytest.fixture(scope="module")
def scripted(tmp_path_factory):
    """scripted.blend and the two marker paths its scripts would touch."""
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    folder = tmp_path_factory.mktemp("scripts")
    text_marker, driver_marker = folder / "text-ran", folder / "driver-ran"
    scene = build_showcase(32, 24)
    camera = scene.camera
    camera.keyframe_insert("location", frame=1)
    camera.location.x -= 0.5
    camera.keyframe_insert("location", frame=2)
    text = bpy.data.texts.new("autorun.py")
    text.write(_touch(text_marker) + "\n")
    text.use_module = True
    mesh = next(obj for obj in scene.objects if obj.type == "MESH")
    driver = mesh.driver_add("location", 2).driver
    driver.type = "SCRIPTED"
    driver.expression = f"({_touch(driver_marker)} or 0) + 0.0"
    assert not driver.is_simple_expression
    bpy.ops.wm.save_as_mainfile(filepath=str(folder / "scripted.blend"))
    bpy.ops.wm.read_homefile(use_empty=True)
    return folder / "scripted.blend", text_marker, driver_marker


def _python(code, cwd):
    """``code`` run by this Python in a new process (ended by os._exit for the control: bpy 4.5
    hangs in a static destructor at exit after a scripted driver ran; ``phrt`` ends the same way)."""
    return subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=600)


def test_the_control_opened_with_scripts_allowed_runs_both(scripted, tmp_path):
    blend, text_marker, driver_marker = scripted
    for marker in (text_marker, driver_marker):
        marker.unlink(missing_ok=True)
    done = _python(f"import bpy; bpy.ops.wm.open_mainfile(filepath={str(blend)!r}, use_scripts=True); "
                   f"bpy.context.scene.frame_set(2); bpy.context.view_layer.update(); "
                   f"import os, sys; sys.stdout.flush(); os._exit(0)", tmp_path)
    assert done.returncode == 0, done.stderr
    assert text_marker.exists() and driver_marker.exists()


def test_phrt_render_runs_neither_and_warns_once(scripted, tmp_path):
    blend, text_marker, driver_marker = scripted
    for marker in (text_marker, driver_marker):
        marker.unlink(missing_ok=True)
    done = _python("import sys, bpy; bpy.context.preferences.filepaths.use_scripts_auto_execute = True; "
                   "from phrt.cli import main; "
                   f"sys.argv = ['phrt', 'render', {str(blend)!r}, '--frames', '1-2', '--images', 'none', "
                   f"'--resolution', '32x24', '--out', 'run']; main()", tmp_path)
    assert done.returncode == 0, done.stderr
    assert not text_marker.exists() and not driver_marker.exists()
    warnings = [line for line in done.stderr.splitlines() if line.startswith("phrt: warning:")]
    assert len(warnings) == 1 and "not run" in warnings[0], done.stderr
    assert "autorun.py" in warnings[0] and "1 scripted driver" in warnings[0], warnings
