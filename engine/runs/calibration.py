"""Resolving ``budget_at`` (a fraction of the way from raster to ray traced frame time) to
milliseconds for a replay: from existing runs of the same path, or a short calibration.

See ``phrt_addon/select/mode_budgets.py`` for the definition.  The calibration renders
``CALIBRATION_FRAMES`` frames spread over the replayed range in RASTER and in
RAYTRACE mode, after one warm-up frame per mode (shader compiles, Embree
builds), with no images, into a temporary folder that is deleted afterwards.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

from ...phrt_addon.select import mode_budgets
from ...phrt_addon.runs import run_files
from ...phrt_addon.runs import summary as run_summary
from .. import extract

# Measured frames per mode (after one warm-up frame): a few seconds at 640x480 here.
CALIBRATION_FRAMES = 3


def calibrate(scene, camera, frame_range, fraction, *, runner, resolution=None,
              scene_label=None) -> mode_budgets.BudgetResolution:
    """Render a few frames of each mode and resolve ``fraction`` from their steady means.
    ``runner`` is ``replay.ReplayRun`` (passed in: the replay resolves its budget here)."""
    frames = mode_budgets.calibration_frames(frame_range, CALIBRATION_FRAMES)
    means = {}
    with tempfile.TemporaryDirectory(prefix="phrt-calibration-") as folder:
        for mode in ("RASTER", "RAYTRACE"):
            run_dir = Path(folder) / mode.lower()
            run = runner(scene, camera, frame_range, mode, run_dir, images="none", resolution=resolution,
                                scene_label=scene_label, frame_list=[frames[0], *frames])
            while run.remaining:
                run.step()
            run.finish()
            means[mode] = mode_budgets.steady_mean_ms(run_files.read_frames(run_dir)[1:])
    return mode_budgets.BudgetResolution(fraction=float(fraction), raster_ms=means["RASTER"], raytrace_ms=means["RAYTRACE"],
                                   method="calibration",
                                   detail={"calibration_frames": frames, "warm_up_frames": 1})


def resolve(scene, camera, frame_range, fraction, *, runner, resolution=None, scene_label=None,
            search_dirs=()) -> mode_budgets.BudgetResolution:
    """From complete raster and raytrace runs of this path among ``search_dirs`` on this CPU, else
    by calibration."""
    width, height = resolution if resolution is not None else extract.resolution(scene)
    label = scene_label or scene.name
    runs = mode_budgets.find_reference_runs(search_dirs, label, camera.name, (width, height),
                                            run_summary.machine_info()["cpu_model"])
    if runs is not None:
        return mode_budgets.from_runs(fraction, *runs)
    return calibrate(scene, camera, frame_range, fraction, runner=runner, resolution=resolution,
                     scene_label=scene_label)
