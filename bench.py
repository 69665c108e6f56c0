"""``make bench``: figures and ratios measured in one run (not timed tests).

1. Selection heuristic: ms per frame for 10 .. 100,000 candidates and the growth ratio.
2. Trace stage vs raw embreex on the very same rays (shadow, primary, reflection).
3. A replay of the first frames of a sample path in raster, hybrid and raytrace
   modes: ms per stage and the hybrid/raster and raytrace/raster ratios.

    python -m phrt.bench [--scene arcade] [--frames 1-12] [--skip-replay]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path


def replay_bench(scene_name, frames, out=print):
    from . import cli
    from .engine import replay
    from .phrt_addon import runlog
    cli._blender()
    import bpy
    label = cli.load_scene(scene_name)
    scene = bpy.context.scene
    camera = replay.find_path(scene, None)
    frame_range = replay.parse_frames(frames, replay.path_frame_range(scene, camera))
    rows = {}
    budget_ms = None
    with tempfile.TemporaryDirectory(prefix="phrt-bench-") as temp:
        # Raster and raytrace first: the hybrid run's budget (the scene's Budget At) resolves from them.
        for mode in ("RASTER", "RAYTRACE", "HYBRID"):
            with cli._quiet_stdout():
                result = replay.replay(scene, camera, frame_range, mode, Path(temp) / mode, images="none",
                                       scene_label=label)
            frames_read = runlog.read_frames(result.run_dir)[1:] or runlog.read_frames(result.run_dir)
            mean = {key: sum(float(r[key] or 0) for r in frames_read) / len(frames_read)
                    for key in ("total_ms", "raster_ms", "select_ms", "trace_ms", "composite_ms", "rays",
                                "n_selected")}
            rows[mode] = mean
            if mode == "HYBRID":
                budget_ms = result.summary["budget_ms"]
    out(f"\nReplay of {label}/{camera.name} frames {frames} at {scene.render.resolution_x}x"
        f"{scene.render.resolution_y}, budget {budget_ms:.0f} ms (means over warm frames)")
    out(f"{'mode':>9} {'total':>8} {'raster':>8} {'select':>7} {'trace':>8} {'compos.':>8} {'rays':>9} {'traced':>7}")
    for mode in ("RASTER", "HYBRID", "RAYTRACE"):
        mean = rows[mode]
        out(f"{mode.lower():>9} {mean['total_ms']:8.1f} {mean['raster_ms']:8.1f} {mean['select_ms']:7.1f} "
            f"{mean['trace_ms']:8.1f} {mean['composite_ms']:8.1f} {mean['rays']:9.0f} {mean['n_selected']:7.1f}")
    raster = rows["RASTER"]["total_ms"]
    out(f"ratios: hybrid/raster {rows['HYBRID']['total_ms'] / raster:.2f}, "
        f"raytrace/raster {rows['RAYTRACE']['total_ms'] / raster:.2f}, "
        f"raytrace/hybrid {rows['RAYTRACE']['total_ms'] / rows['HYBRID']['total_ms']:.2f}")
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description="PHRT benchmarks")
    parser.add_argument("--scene", default="arcade")
    parser.add_argument("--frames", default="1-12")
    parser.add_argument("--skip-replay", action="store_true")
    args = parser.parse_args(argv)
    from .phrt_addon import selection_bench
    print("Selection heuristic (phrt_addon/selection_bench.py)")
    selection_bench.run()
    try:
        from .phrt_addon import trace_bench
    except ImportError:
        trace_bench = None
    if trace_bench is not None:
        print("\nTrace stage vs raw embreex (phrt_addon/trace_bench.py)")
        trace_bench.run()
    if not args.skip_replay:
        replay_bench(args.scene, args.frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
