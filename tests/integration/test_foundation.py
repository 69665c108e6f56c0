"""Foundation: registration, a user's install from the zip, a known scene read back
from the GPU, and errors reaching the caller."""
import math
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from exr_passes import read_passes

ROOT = Path(__file__).resolve().parents[2]


def test_register_unregister_register_leaves_nothing_behind(blender):
    import phrt
    bpy = blender
    phrt.unregister()
    try:
        assert not hasattr(bpy.types.Object, "phrt")
        assert not hasattr(bpy.types.Material, "phrt")
        assert not hasattr(bpy.types.Scene, "phrt")
        assert "PHRT" not in _engine_ids(bpy)
        assert "PHRT" not in bpy.types.RENDER_PT_format.COMPAT_ENGINES
    finally:
        phrt.register()
    assert hasattr(bpy.types.Object, "phrt") and hasattr(bpy.types.Scene, "phrt")
    assert "PHRT" in bpy.types.RENDER_PT_format.COMPAT_ENGINES
    assert "PHRT" in _engine_ids(bpy)
    bpy.ops.wm.read_homefile(use_empty=True)  # defaults are checked on a new file
    scene = bpy.context.scene
    assert scene.phrt.max_area_fraction == pytest.approx(0.40)
    assert scene.phrt.mode == "HYBRID"


def _engine_ids(bpy):
    """Engine ids Blender accepts right now (the RNA enum of engines is static; assignment is not)."""
    scene = bpy.context.scene
    previous = scene.render.engine
    try:
        scene.render.engine = "PHRT"
        return {"PHRT"}
    except TypeError:
        return set()
    finally:
        if previous != "PHRT" or "PHRT" in getattr(bpy.types, "RENDER_PT_format").COMPAT_ENGINES:
            try:
                scene.render.engine = previous
            except TypeError:
                pass


def _known_scene(bpy, mode="RAYTRACE", width=160, height=120):
    """A candidate cube straight ahead of the camera at 5 m, a non-candidate sphere to its
    right lit by a sun from the right."""
    from phrt.sample_scenes import showcase
    scene = showcase.empty_scene(width, height)
    scene.phrt.mode = mode
    scene.world.color = (0.0, 0.0, 0.0)
    cube = showcase.mesh_object("Target", showcase.cube(1.0), showcase.principled("Grey", (0.5, 0.5, 0.5)),
                                location=(0.0, 0.0, 0.0))
    showcase.tag(cube, priority=1.0)
    showcase.mesh_object("Ball", showcase.sphere(0.6), showcase.principled("White", (0.8, 0.8, 0.8)),
                         location=(1.6, 0.0, 0.0), smooth=True)
    # The sun travels along -X (the lamp's -Z turned by +90 degrees about Y): it lights the +X
    # side of everything, and the cube (at -X of the ball) casts no shadow on the ball.
    showcase.add_light("SUN", (5, 0, 0), 4.0, rotation=(0.0, math.radians(90), 0.0), name="Sun")
    camera = showcase.add_camera((0.0, -5.5, 0.0), (0.0, 0.0, 0.0), lens=35.0)
    return scene, camera


def test_known_scene_reads_back_ids_depth_and_light(blender, render_exr):
    scene, _ = _known_scene(blender, "RAYTRACE")
    passes = read_passes(render_exr())
    height, width = passes["Depth"].shape
    cy, cx = height // 2, width // 2
    # The object at the image centre is the candidate cube, the one on the right is not.
    assert passes["PHRT Candidate"][cy, cx] == 1.0
    assert passes["PHRT Selected"][cy, cx] == 1.0
    ball_column = int(width / 2 + 1.6 / 5.0 * (35.0 / 36.0) * width) - 1  # projected ball centre
    assert passes["Combined"][cy, ball_column].sum() > 0, "the ball is drawn where it is projected"
    assert passes["PHRT Candidate"][cy, ball_column] == 0.0
    # The cube's front face is 5.0 m along the view axis (camera at -5.5, face at -0.5).
    assert passes["Depth"][cy, cx] == pytest.approx(5.0, rel=0.01)
    # Rows: the top of the image is above the cube (background far away).
    assert passes["Depth"][2, cx] > 1e3
    combined = passes["Combined"]
    assert np.all(np.isfinite(combined)) and np.all(np.isfinite(passes["Normal"]))
    # Lit side (+X, right in the image) of the ball is brighter than its unlit side.
    ball = np.flatnonzero((passes["PHRT Candidate"][cy] == 0) & (passes["Depth"][cy] < 1e3))
    ball = ball[ball > cx]
    left, right = ball.min(), ball.max()
    assert combined[cy, right - 2, :3].mean() > 4 * combined[cy, left + 2, :3].mean() + 1e-3
    # The normal pass of the cube's front face points back at the camera (-Y).
    assert passes["Normal"][cy, cx] == pytest.approx([0.0, -1.0, 0.0], abs=1e-3)


def test_exception_in_pipeline_reaches_caller_as_runtime_error(blender, monkeypatch):
    from phrt.phrt_addon import frame
    _known_scene(blender, "HYBRID")

    def broken(*args, **kwargs):
        raise ValueError("the selection graph could not be built")

    monkeypatch.setattr(frame.FrameRenderer, "render", broken)
    with pytest.raises(RuntimeError, match="selection graph could not be built"):
        blender.ops.render.render()


def test_scene_without_camera_is_a_readable_error(blender):
    from phrt.sample_scenes import showcase
    scene = showcase.empty_scene(64, 48)
    showcase.mesh_object("Box", showcase.cube(1.0))
    with pytest.raises(RuntimeError, match="[Cc]amera"):
        blender.ops.render.render()
    assert scene.camera is None


INSTALL_SCRIPT = textwrap.dedent("""
    import sys, tempfile, pathlib
    import numpy as np
    import bpy
    zip_path, out = sys.argv[-2], sys.argv[-1]
    bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    import addon_utils
    enabled = [m.__name__ for m in addon_utils.modules() if addon_utils.check(m.__name__)[1]]
    assert "bl_ext.user_default.phrt" in enabled, enabled
    assert "bl_ext.user_default.phrt" in sys.modules
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "PHRT"
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 96, 72, 100
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    cube = bpy.context.active_object
    cube.phrt.candidate = True
    scene.phrt.mode = "RAYTRACE"
    light = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    scene.collection.objects.link(light)
    cam = bpy.data.objects.new("Cam", bpy.data.cameras.new("Cam"))
    cam.location = (0, -4, 0); cam.rotation_euler = (1.5707963, 0, 0)
    scene.collection.objects.link(cam); scene.camera = cam
    scene.render.image_settings.file_format = "PNG"
    scene.render.filepath = out
    bpy.ops.render.render(write_still=True)
    import embreex
    assert "bl_ext.user_default.phrt.engine" in sys.modules
    assert "dask" not in sys.modules and "distributed" not in sys.modules  # optional: sweeps on a cluster only
    print("PHRT-ZIP-OK", embreex.__file__)
""")


@pytest.mark.slow
def test_user_installs_zip_and_renders(tmp_path):
    dist = tmp_path / "dist"
    build = subprocess.run([sys.executable, str(ROOT / "tools" / "build_extension.py"), "--platforms", "linux-x64",
                            "--out", str(dist)], capture_output=True, text=True, cwd=ROOT)
    assert build.returncode == 0, build.stdout + build.stderr
    zip_path = next(dist.glob("phrt-*-linux_x64.zip"))
    import zipfile
    files = zipfile.ZipFile(zip_path).namelist()
    # the extension ships its engine, UI and the command line, not the demo, the paper runner or benches
    assert {"__init__.py", "engine/__init__.py", "cli/__init__.py", "phrt_addon/frame.py"} <= set(files)
    assert not [name for name in files if name in ("cli/demo.py", "cli/paper.py", "cli/bench.py")
                or name.startswith(("benchmarks/", "tests/", "tools/", "docs/"))]
    bundled = [name for name in files if name.startswith("wheels/")]
    assert any("embreex" in name for name in bundled)
    assert not [name for name in bundled if any(optional in name.lower() for optional in ("dask", "distributed", "bokeh"))]
    script = tmp_path / "install.py"
    script.write_text(INSTALL_SCRIPT)
    out = tmp_path / "frame.png"
    env = {"BLENDER_USER_RESOURCES": str(tmp_path / "user"), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    run = subprocess.run([sys.executable, str(script), str(zip_path), str(out)], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=600)
    assert run.returncode == 0 and "PHRT-ZIP-OK" in run.stdout, run.stdout[-3000:] + run.stderr[-3000:]
    assert out.exists() and out.stat().st_size > 0
    from phrt.phrt_addon.report.metrics import read_image
    image = read_image(out)
    assert image.shape[:2] == (72, 96)
    assert image[36, 48].sum() > 0.05  # the lit cube is in the middle
