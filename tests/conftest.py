"""Shared pytest set-up.

Core tests (tests/core) never import bpy.  Integration tests get Blender (the
bpy module) through the ``blender`` fixture, with the PHRT add-on registered
from the checkout and Blender's user resources in a temporary folder, so no
test reads or writes the developer's Blender configuration.  ``phrt.register()``
unregisters the add-on again when the interpreter ends, so the pytest process exits
cleanly on every Blender of the matrix (4.5 would hang otherwise).
"""
import os
import tempfile

import pytest

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-blender-user-"))


@pytest.fixture(scope="session")
def blender():
    import bpy

    import phrt
    if not hasattr(bpy.types.Scene, "phrt"):
        phrt.register()
    return bpy


@pytest.fixture
def render_exr(blender, tmp_path):
    """Render the current scene with PHRT to a multilayer EXR and return its path."""
    from phrt import compat
    def render(name="frame"):
        scene = blender.context.scene
        settings = scene.render.image_settings
        compat.set_image_format(settings, compat.MULTILAYER_EXR)
        settings.color_depth = "32"
        scene.render.use_file_extension = True
        scene.render.filepath = str(tmp_path / name)
        blender.ops.render.render(write_still=True)
        return tmp_path / f"{name}.exr"
    return render


@pytest.fixture
def fresh_caches(blender):
    """Each test starts and ends with nothing cached (GPU resources, Embree scenes, meshes)."""
    from phrt.engine import final
    final.release_caches()
    yield
    final.release_caches()


@pytest.fixture
def closing():
    """``closing(scene)``: the Embree scenes (``TraceScene``) a test built, closed after it."""
    scenes = []
    yield scenes.append
    for scene in scenes:
        scene.close()
