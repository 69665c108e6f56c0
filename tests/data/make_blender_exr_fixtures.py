"""Regenerate the Blender 5.0.1 image fixtures read by tests/core/test_metrics.py.

Run with the project's venv (bpy 5.0.1), from the repository root:

    .venv/bin/python tests/data/make_blender_exr_fixtures.py

It writes, at 32x24:

- ``blender501_phrt_passes.exr``: a multilayer EXR from a tiny Python
  RenderEngine that registers the passes PHRT writes (Combined, Depth, Normal,
  PHRT Selected, PHRT Candidate) and fills them with a known pattern:
  Combined R = x / (W-1), G = (row counted from the bottom) / (H-1), B = 0.25,
  A = 1, plus an HDR red block (2, 0, 0) in the 4x4 top-left pixels;
  Depth = 1 + row counted from the bottom; PHRT Selected = 1 on the left half;
  PHRT Candidate = 1 on the top half.  Combined is half float, as Blender
  writes it with colour depth '16'.
- ``blender501_phrt_passes.png``: the same render as an 8-bit sRGB PNG with the
  'Standard' view transform.
- ``blender501_workbench.exr``: the default scene rendered by Workbench with the
  Z and Normal passes enabled (Workbench writes Combined and Depth only).
"""
import os
import sys

import bpy
import numpy as np

WIDTH, HEIGHT = 32, 24
HERE = os.path.dirname(os.path.abspath(__file__))


class FixtureEngine(bpy.types.RenderEngine):
    bl_idname = "PHRT_FIXTURE"
    bl_label = "PHRT fixture"

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)

    def update_render_passes(self, scene=None, renderlayer=None):
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", 'COLOR')
        self.register_pass(scene, renderlayer, "Depth", 1, "Z", 'VALUE')
        self.register_pass(scene, renderlayer, "Normal", 3, "XYZ", 'VECTOR')
        self.register_pass(scene, renderlayer, "PHRT Selected", 1, "X", 'VALUE')
        self.register_pass(scene, renderlayer, "PHRT Candidate", 1, "X", 'VALUE')

    def render(self, depsgraph):
        # Blender's pass buffers run bottom row first.
        x = np.tile(np.arange(WIDTH, dtype=np.float32), (HEIGHT, 1))
        row_up = np.tile(np.arange(HEIGHT, dtype=np.float32)[:, None], (1, WIDTH))
        combined = np.stack([x / (WIDTH - 1), row_up / (HEIGHT - 1),
                             np.full_like(x, 0.25), np.ones_like(x)], axis=-1)
        combined[HEIGHT - 4:, :4, :3] = (2.0, 0.0, 0.0)
        normal = np.zeros((HEIGHT, WIDTH, 3), np.float32)
        normal[..., 2] = 1.0
        planes = {
            "Combined": combined,
            "Depth": 1.0 + row_up,
            "Normal": normal,
            "PHRT Selected": (x < WIDTH / 2).astype(np.float32),
            "PHRT Candidate": (row_up >= HEIGHT / 2).astype(np.float32),
        }
        result = self.begin_result(0, 0, WIDTH, HEIGHT)
        layer = result.layers[0]
        for name, plane in planes.items():
            render_pass = layer.passes[name]
            flat = np.ascontiguousarray(plane, dtype=np.float32).ravel()
            assert flat.size == WIDTH * HEIGHT * render_pass.channels, name
            render_pass.rect.foreach_set(flat)
        self.end_result(result)


def _setup(engine):
    scene = bpy.context.scene
    scene.render.engine = engine
    scene.render.resolution_x, scene.render.resolution_y = WIDTH, HEIGHT
    scene.render.resolution_percentage = 100
    layer = scene.view_layers[0]
    layer.use_pass_z = True
    layer.use_pass_normal = True
    settings = scene.render.image_settings
    settings.media_type = 'MULTI_LAYER_IMAGE'
    settings.color_depth = '16'
    settings.exr_codec = 'ZIP'
    return scene


def _render(scene, name):
    scene.render.filepath = os.path.join(HERE, name)
    bpy.ops.render.render(write_still=True)


def main():
    bpy.utils.register_class(FixtureEngine)
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = _setup("PHRT_FIXTURE")
    camera = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    _render(scene, "blender501_phrt_passes.exr")
    settings = scene.render.image_settings
    settings.media_type = 'IMAGE'
    settings.file_format = 'PNG'
    settings.color_depth = '8'
    settings.color_mode = 'RGB'
    scene.view_settings.view_transform = 'Standard'
    _render(scene, "blender501_phrt_passes.png")

    bpy.ops.wm.read_homefile(use_empty=False)
    scene = _setup("BLENDER_WORKBENCH")
    _render(scene, "blender501_workbench.exr")
    return 0


if __name__ == "__main__":
    sys.exit(main())
