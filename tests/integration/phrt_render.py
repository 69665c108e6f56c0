"""Rendering a frame through Blender with PHRT for the extreme-case tests, and the checks every
such frame must pass: every value of every pass of the written EXR is finite, and so is every
number of the frame's statistics and selection rows (what the logs and the report are made of).

Set ``PHRT_TEST_IMAGES=<dir>`` to keep a PNG of every rendered frame for a look."""
from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np

from phrt import compat
from phrt.engine import extract, session
from phrt.phrt_addon.report import metrics
from exr_passes import read_passes

MODES = ("RASTER", "HYBRID", "RAYTRACE")
PHRT = Path(sys.executable).with_name("phrt")


def run_phrt(args, cwd, timeout=900):
    """``.venv/bin/phrt ARGS`` in ``cwd``: (exit status, stdout, stderr lines but EGL's noise)."""
    process = subprocess.run([str(PHRT), *args], cwd=cwd, capture_output=True, text=True, timeout=timeout)
    errors = [line for line in process.stderr.splitlines() if line.strip() and "EGL" not in line]
    return process.returncode, process.stdout, errors


def job_lines(stdout):
    """{job id: the rest of its progress line} from a sweep's output."""
    found = {}
    for line in stdout.splitlines():
        if line.startswith("phrt: [") and "] " in line:
            job, rest = line.split("] ", 1)[1].split(": ", 1)
            found[job] = rest
    return found


def save_moving_showcase(path: Path, width: int, height: int) -> Path:
    """The showcase scene with its camera moving 1 unit along x over frames 1-3, saved to
    ``path`` (a path to replay and sweep); the session is left with an empty file."""
    from phrt.sample_scenes.showcase import build_showcase
    scene = build_showcase(width, height)
    camera = scene.camera
    camera.keyframe_insert("location", frame=1)
    camera.location.x -= 1.0
    camera.keyframe_insert("location", frame=3)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


def assert_finite_logs():
    """No NaN or Inf in the last frame's statistics or selection rows."""
    frame = session.last_frame()
    for key, value in frame.stats.items():
        if isinstance(value, float):
            assert math.isfinite(value), f"stats[{key}] = {value}"
    for row in frame.rows:
        for key, value in row.items():
            if isinstance(value, float):
                assert math.isfinite(value), f"selection row {row['element']}: {key} = {value}"


def render(scene, mode, name, tmp_path):
    """Render the scene's frame in ``mode`` to a multilayer EXR; returns its passes (top row first)
    after checking passes and logs are finite."""
    scene.render.engine = "PHRT"
    scene.phrt.mode = mode
    settings = scene.render.image_settings
    compat.set_image_format(settings, compat.MULTILAYER_EXR)
    settings.color_depth = "32"
    scene.render.use_file_extension = True
    path = Path(tmp_path) / f"{name}-{mode}.exr"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    passes = read_passes(path)
    assert "Combined" in passes, sorted(passes)
    for pass_name, pixels in passes.items():
        bad = ~np.isfinite(pixels)
        assert not np.any(bad), f"{name} {mode}: {bad.sum()} NaN/Inf values in pass {pass_name}"
    assert session.last_frame().stats["mode"] == mode
    assert_finite_logs()
    keep = os.environ.get("PHRT_TEST_IMAGES")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        metrics.write_image(Path(keep) / f"{name}-{mode}.png", passes["Combined"][..., :3])
    return passes


def set_world(scene, color):
    """The world colour PHRT shades with: the Background node's (Blender 5 worlds use nodes)."""
    scene.world.color = color
    if scene.world.node_tree is not None:
        background = next((n for n in scene.world.node_tree.nodes if n.type == "BACKGROUND"), None)
        if background is not None:
            background.inputs["Color"].default_value = (*color, 1.0)
            background.inputs["Strength"].default_value = 1.0


def selected_elements():
    return {row["element"] for row in session.last_frame().rows if row["selected"]}


def camera_rays():
    """Origins and unit directions through every pixel centre, (h, w, 3), top row first."""
    snapshot = extract.extract(bpy.context.evaluated_depsgraph_get())
    origins, directions = snapshot.camera.pixel_rays()
    return origins[::-1], directions[::-1]


def plane_hit(origins, directions, height):
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (height - origins[..., 2]) / directions[..., 2]
    return np.where(np.isfinite(t) & (t > 0), t, np.inf)


def box_hit(origins, directions, low, high):
    """Distance to the entry point of an axis-aligned box along rays (inf on a miss)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0 = (np.asarray(low, float) - origins) / directions
        t1 = (np.asarray(high, float) - origins) / directions
    near = np.max(np.nan_to_num(np.minimum(t0, t1), nan=-np.inf), axis=-1)
    far = np.min(np.nan_to_num(np.maximum(t0, t1), nan=np.inf), axis=-1)
    return np.where((far >= np.maximum(near, 0.0)) & (far > 0), np.maximum(near, 0.0), np.inf)


def erode(mask, steps=1):
    """Pixels whose 4 neighbours (``steps`` times over) are in ``mask`` too."""
    for _ in range(steps):
        padded = np.pad(mask, 1)
        mask = mask & padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:]
    return mask
