"""The lights' one table (engine/gpu/light_struct.py): the GLSL ``LightData`` text it writes and
the floats ``pack()`` writes agree field by field, for every light kind.

The struct text is parsed here on its own (std140 offsets of vec4 and mat4 members), and a
shader compiled against that text reads every member of every light slot back by name: the
driver's layout, not the table's, decides what it reads.  Each part then holds what the light
means (its kind's code, the spot cone and soft radius of phrt_addon/scene/lights.py, its shadow views).
"""
import math
import os
import re
import tempfile

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="phrt-test-user-"))

import numpy as np  # noqa: E402
import pytest  # noqa: E402

bpy = pytest.importorskip("bpy")

from phrt.engine import extract  # noqa: E402
from phrt.engine.gpu import fullscreen, light_struct, readback, uniforms  # noqa: E402
from phrt.engine.gpu.frame import GPUFrame  # noqa: E402
from phrt.engine.gpu.lighting import LIGHTS_PER_PASS  # noqa: E402
from phrt.phrt_addon.scene import lights  # noqa: E402
from phrt.sample_scenes import showcase  # noqa: E402

from gpu_probe import run_on_gpu  # noqa: E402

pytestmark = pytest.mark.usefixtures("fresh_caches")

MEMBER = re.compile(r"^\s*(vec4|mat4)\s+(\w+)(?:\[(\d+)\])?;", re.MULTILINE)


def std140_members(struct_text: str) -> list:
    """(member, array index, column, float offset) of every vec4 a struct of vec4 and mat4
    members holds, from its GLSL text: each 16 floats (mat4) or 4 (vec4), arrays back to back."""
    body = struct_text[struct_text.index("struct LightData"):struct_text.index("};")]
    vec4s, offset = [], 0
    for glsl_type, name, count in MEMBER.findall(body):
        for index in range(int(count or 1)):
            for column in range(4 if glsl_type == "mat4" else 1):
                vec4s.append((name, index if count else None, column if glsl_type == "mat4" else None, offset))
                offset += 4
    return vec4s


def probe_source(vec4s) -> str:
    """A fragment shader writing, at pixel (k, slot), the k-th vec4 of light ``slot``, read by name."""
    lines = ["vec4 member(int slot, int k) {"]
    for k, (name, index, column, _) in enumerate(vec4s):
        access = name + (f"[{index}]" if index is not None else "") + (f"[{column}]" if column is not None else "")
        lines.append(f"  if (k == {k}) {{ return lights.light[slot].{access}; }}")
    lines += ["  return vec4(-1.0);", "}", "",
              "void main() {", "  ivec2 pixel = ivec2(gl_FragCoord.xy);",
              "  out_member = member(pixel.y, pixel.x);", "}"]
    return "\n".join(lines) + "\n"


def lights_of_every_kind():
    showcase.build_showcase(96, 72)  # a sun and a point light (cube map)
    showcase.add_light("SPOT", (-2.0, -1.0, 3.0), 400.0, rotation=(math.radians(30), 0.0, math.radians(-60)),
                       name="Spot", spot_size=math.radians(60), spot_blend=0.3)
    showcase.add_light("AREA", (0.0, 2.0, 3.0), 200.0, rotation=(math.radians(-20), 0.0, 0.0), name="Panel",
                       shadow_soft_size=0.0)
    showcase.add_light("POINT", (1.5, -2.0, 1.5), 150.0, color=(1.0, 0.6, 0.3), name="Bulb", shadow_soft_size=0.4)
    bpy.data.objects["Bulb"].data.use_shadow = False
    return bpy.context.scene


def test_the_glsl_light_struct_and_the_packed_floats_agree_field_by_field_for_every_kind():
    scene = lights_of_every_kind()
    struct_text = light_struct.light_set_glsl()
    vec4s = std140_members(struct_text)
    assert len(vec4s) * 4 == uniforms.floats(light_struct.LIGHT)

    def job(engine, depsgraph):
        snapshot = extract.extract(depsgraph)
        frame = GPUFrame(snapshot)
        frame.draw()
        camera = snapshot.camera.position
        packed = np.zeros((LIGHTS_PER_PASS, uniforms.floats(light_struct.LIGHT)), np.float32)
        atlases = []
        for slot, light in enumerate(snapshot.lights):
            atlases.append(frame.atlases.get(slot) if light.cast_shadows else None)
            packed[slot] = light_struct.pack(light, atlases[-1], camera)
        import gpu
        shader = fullscreen.build(gpu, struct_text, (), (("VEC4", "out_member"),), probe_source(vec4s),
                                  uniform_blocks=(("LightSet", "lights"),), layers={"layers": ()},
                                  extra_defines={"LIGHTS_PER_PASS": str(LIGHTS_PER_PASS)})
        target = gpu.types.GPUTexture((len(vec4s), LIGHTS_PER_PASS), format="RGBA32F")
        framebuffer = gpu.types.GPUFrameBuffer(color_slots=(target,))
        block = uniforms.upload(gpu, packed.ravel())
        with framebuffer.bind():
            gpu.state.viewport_set(0, 0, len(vec4s), LIGHTS_PER_PASS)
            shader.bind()
            shader.uniform_block("lights", block)
            frame.resources.fullscreen_batch(shader).draw(shader)
        read = readback.read(gpu, framebuffer, 0, "FLOAT", 4, len(vec4s), LIGHTS_PER_PASS)
        return snapshot.lights, atlases, camera, packed, np.array(read)

    scene_lights, atlases, camera, packed, read = run_on_gpu(scene, job)
    kinds = [lights.kind(light) for light in scene_lights]
    assert sorted(set(kinds)) == list(lights.LightKind)
    n = len(scene_lights)
    # The shader read, by name, exactly the floats packed at the text's std140 offsets.
    for k, (name, index, column, offset) in enumerate(vec4s):
        np.testing.assert_array_equal(read[:n, k], packed[:n, offset:offset + 4], err_msg=f"{name}[{index}][{column}]")
    # Each part holds what it means.
    for slot, (light, atlas) in enumerate(zip(scene_lights, atlases)):
        part = uniforms.Packed(light_struct.LIGHT, packed[slot]).get
        kind = lights.kind(light)
        assert part("kind")[0] == int(kind)
        np.testing.assert_allclose(part("color"), light.color, rtol=1e-6)
        np.testing.assert_allclose(part("position"), np.asarray(light.position) - camera, rtol=1e-6, atol=1e-6)
        assert part("radius")[0] == np.float32(lights.soft_radius(light))
        np.testing.assert_allclose(np.linalg.norm(part("direction")), 1.0, rtol=1e-6)
        cone = lights.spot_cone(light) if kind is lights.LightKind.SPOT else (0.0, 0.0)
        np.testing.assert_array_equal(part("cos_outer")[0], np.float32(cone[0]))
        np.testing.assert_array_equal(part("cos_inner")[0], np.float32(cone[1]))
        views = {lights.LightKind.SUN: 1, lights.LightKind.SPOT: 1}.get(kind, 6) if light.cast_shadows else 0
        assert part("views")[0] == views and part("has_map")[0] == float(views > 0)
        for face in range(views):
            view = atlas.views[face]
            np.testing.assert_array_equal(part("face_view_proj", face),
                                          np.asarray(view.view_proj_relative, np.float32).T.ravel())
            np.testing.assert_array_equal(part("face_axis", face), view.view[2, :3].astype(np.float32))
        if views:
            assert part("view_size")[0] == atlas.face_size and part("near")[0] == np.float32(atlas.views[0].near)
    assert [light.name for light, atlas in zip(scene_lights, atlases) if atlas is None] == ["Bulb"]
