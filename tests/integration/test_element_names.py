"""Element names in a rendered frame's selection rows are unique by construction: an object named
``Door/Pane`` and the tagged material ``Pane`` of object ``Door`` (the issue's ``Wall/Glass`` case) stay two elements (they used to
merge into one silently)."""
import os
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")

from phrt.engine import session  # noqa: E402
from phrt.sample_scenes import showcase  # noqa: E402
from phrt_render import render  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_caches")


def test_an_object_named_wall_slash_glass_and_walls_glass_material_are_two_elements(tmp_path):
    scene = showcase.build_showcase(48, 36)
    glass = showcase.principled("Pane", color=(0.9, 0.9, 1.0), transmission=1.0)
    glass.phrt.candidate = True
    brick = showcase.principled("Brick", color=(0.6, 0.3, 0.2))
    wall = showcase.mesh_object("Door", showcase.cube(0.4), brick, location=(0.6, 0.0, 0.4))
    wall.data.materials.append(glass)
    for index, polygon in enumerate(wall.data.polygons):
        polygon.material_index = index % 2
    slashed = showcase.mesh_object("Door/Pane", showcase.cube(0.3), brick, location=(-0.6, 0.2, 0.3))
    slashed.phrt.candidate = True
    render(scene, "HYBRID", "names", tmp_path)
    names = [row["element"] for row in session.last_frame().rows]
    assert len(names) == len(set(names))
    assert "Door/Pane" in names and "Door\\/Pane" in names  # the Wall/Glass case
