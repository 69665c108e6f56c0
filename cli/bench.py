"""``make bench``: figures and ratios measured in one run (not timed tests).

1. Selection heuristic: ms per frame for 10 .. 100,000 candidates and the growth ratio.
2. Trace stage vs raw embreex on the very same rays (shadow, primary, reflection).
3. A replay of the first frames of a sample path in raster, hybrid and raytrace
   modes: ms per stage and the hybrid/raster and raytrace/raster ratios.
4. The GPU frame (issue 9): on arcade/path1 and atrium/path1 frames 200-259 at
   640x480, PHRT raster against Blender's Workbench (no anti-aliasing, shadows and
   specular on) per frame, the lighting pass against the G-buffer pass, hybrid at a
   budget one third of the way from raster to raytrace mean frame time (mean and
   p95 against the budget), and Table II's shape beside the paper's ratios.

    python -m phrt.cli.bench [--scene arcade] [--frames 1-12] [--skip-replay]
                         [--gpu-frames 200-259] [--skip-gpu-frame]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path


def replay_bench(scene_name, frames, out=print):
    from . import blender_process
    from ..engine.runs import replay
    from ..engine.runs import camera_path
    from ..phrt_addon.runs import run_files
    blender_process.blender()
    import bpy
    label = blender_process.load_scene(scene_name)
    scene = bpy.context.scene
    camera = camera_path.find_path(scene, None)
    frame_range = camera_path.parse_frames(frames, camera_path.path_frame_range(scene, camera))
    rows = {}
    budget_ms = None
    with tempfile.TemporaryDirectory(prefix="phrt-bench-") as temp:
        # Raster and raytrace first: the hybrid run's budget (the scene's Budget At) resolves from them.
        for mode in ("RASTER", "RAYTRACE", "HYBRID"):
            with blender_process.quiet_stdout():
                result = replay.replay(scene, camera, frame_range, mode, Path(temp) / mode, images="none",
                                       scene_label=label)
            frames_read = run_files.read_frames(result.run_dir)[1:] or run_files.read_frames(result.run_dir)
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


# The paper's Table II (ms per frame): raster, hybrid, ray tracing per path.
PAPER_TABLE_II = {
    "sponza": ((15.2, 102.2, 361.7), (22.1, 117.3, 398.5), (25.2, 139.7, 594.1)),
    "atrium": ((26.7, 165.4, 340.4), (21.8, 125.6, 543.2), (30.6, 207.9, 845.3)),
}


def _paper_ratio_range(index):
    ratios = [row[index] / row[0] for rows in PAPER_TABLE_II.values() for row in rows]
    return min(ratios), max(ratios)


def steady_rows(run_dir):
    """The frames of a run with their one-time work taken out (``total_ms - setup_ms``: shader
    compiles, uploads, new shadow maps, Embree builds), as the budget loop sees them; the first
    frame (cold caches) is left out."""
    from ..phrt_addon.runs import run_files
    rows = run_files.read_frames(run_dir)
    rows = rows[1:] if len(rows) > 1 else rows
    for row in rows:
        row["setup_frame"] = float(row.get("setup_ms") or 0.0) > 1.0
        row["total_ms"] = float(row["total_ms"]) - float(row.get("setup_ms") or 0.0)
    return rows


def column_mean(rows, key):
    """The mean of column ``key`` over ``rows`` (empty cells left out; NaN when none)."""
    values = [float(row[key]) for row in rows if row.get(key) not in (None, "")]
    return sum(values) / len(values) if values else float("nan")


def column_p95(rows, key):
    """The 95th percentile of column ``key`` over ``rows`` (nearest rank)."""
    values = sorted(float(row[key]) for row in rows)
    return values[min(len(values) - 1, int(round(0.95 * (len(values) - 1))))]


def workbench_ms(scene, frames):
    """Wall ms per frame of Blender's Workbench on the same frames (render_aa off, shadows and
    specular on), timed around render.render() like PHRT's wall_ms."""
    import bpy
    engine = scene.render.engine
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.display.render_aa = "OFF"
    scene.display.shading.show_shadows = True
    scene.display.shading.show_specular_highlight = True
    times = []
    try:
        for frame in range(frames[0], frames[1] + 1):
            scene.frame_set(frame)
            start = time.perf_counter()
            bpy.ops.render.render()
            times.append((time.perf_counter() - start) * 1000.0)
    finally:
        scene.render.engine = engine
    return times[1:] if len(times) > 1 else times


def gpu_frame_bench(frames="200-259", scenes=("arcade", "atrium"), out=print):
    """Issue 9's figures, all measured in this one run."""
    from . import blender_process
    from ..engine.runs import replay
    from ..engine.runs import camera_path
    from ..phrt_addon.runs import plan
    blender_process.blender()
    import bpy
    table = []
    with tempfile.TemporaryDirectory(prefix="phrt-bench-gpu-") as temp:
        for scene_name in scenes:
            label = blender_process.load_scene(scene_name)
            scene = bpy.context.scene
            scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 640, 480, 100
            camera = camera_path.find_path(scene, None)
            frame_range = camera_path.parse_frames(frames, camera_path.path_frame_range(scene, camera))
            runs = {}
            for mode in ("RASTER", "RAYTRACE"):
                with blender_process.quiet_stdout():
                    result = replay.replay(scene, camera, frame_range, mode, Path(temp) / f"{label}-{mode}",
                                           images="none", scene_label=label)
                runs[mode] = steady_rows(result.run_dir)
            raster_ms, raytrace_ms = column_mean(runs["RASTER"], "total_ms"), column_mean(runs["RAYTRACE"], "total_ms")
            budget = raster_ms + (raytrace_ms - raster_ms) / 3.0
            with blender_process.quiet_stdout():
                # Table II's hybrid is the paper's heuristic (the baseline), whatever the sample scene's selection.
                result = replay.replay(scene, camera, frame_range, "HYBRID", Path(temp) / f"{label}-HYBRID",
                                       images="none", scene_label=label, budget_ms=budget,
                                       overrides=dict(plan.BASELINE))
            runs["HYBRID"] = steady_rows(result.run_dir)
            hybrid_ms, hybrid_p95 = column_mean(runs["HYBRID"], "total_ms"), column_p95(runs["HYBRID"], "total_ms")
            out(f"\nGPU frame: {label}/{camera.name} frames {frames} at 640x480 (means over frames 2+, "
                f"one-time work taken out)")
            gbuffer, lighting = column_mean(runs["RASTER"], "gbuffer_ms"), column_mean(runs["RASTER"], "composite_ms")
            out(f"  raster: {raster_ms:.1f} ms/frame (wall {column_mean(runs['RASTER'], 'wall_ms'):.1f}); "
                f"G-buffer pass {gbuffer:.1f} ms, lighting + composite {lighting:.1f} ms: "
                f"lighting/G-buffer {lighting / gbuffer:.2f} (target <= 1)")
            if scene_name == "arcade":
                workbench = workbench_ms(scene, frame_range)
                phrt_wall = column_mean(runs["RASTER"], "wall_ms")
                wb = sum(workbench) / len(workbench)
                out(f"  Workbench (no AA, shadows, specular): {wb:.1f} ms/frame; "
                    f"PHRT raster / Workbench {phrt_wall / wb:.3f} (target <= 0.25)")
            out(f"  hybrid at 1/3 of the way raster -> raytrace: budget {budget:.1f} ms, mean {hybrid_ms:.1f} "
                f"({hybrid_ms / budget:.2f}x, target <= 1), p95 {hybrid_p95:.1f} ({hybrid_p95 / budget:.2f}x, "
                f"target <= 1.10), traced {column_mean(runs['HYBRID'], 'n_selected'):.1f} of "
                f"{column_mean(runs['HYBRID'], 'n_visible'):.1f} visible candidates; "
                f"{sum(row['setup_frame'] for row in runs['HYBRID'])} frames with one-time work (taken out)")
            table.append((f"{label}/{camera.name}", raster_ms, hybrid_ms, raytrace_ms))
    low_h, high_h = _paper_ratio_range(1)
    low_r, high_r = _paper_ratio_range(2)
    out("\nTable II shape (ms per frame; the paper's ratios: hybrid/raster "
        f"{low_h:.1f}-{high_h:.1f}x, raytrace/raster {low_r:.1f}-{high_r:.1f}x)")
    out(f"{'path':>16} {'raster':>8} {'hybrid':>8} {'raytrace':>9} {'hyb/ras':>8} {'rt/ras':>7} {'rt/hyb':>7}")
    for path, raster_ms, hybrid_ms, raytrace_ms in table:
        out(f"{path:>16} {raster_ms:8.1f} {hybrid_ms:8.1f} {raytrace_ms:9.1f} {hybrid_ms / raster_ms:8.2f} "
            f"{raytrace_ms / raster_ms:7.2f} {raytrace_ms / hybrid_ms:7.2f}")
    return table


def main(argv=None):
    parser = argparse.ArgumentParser(description="PHRT benchmarks")
    parser.add_argument("--scene", default="arcade")
    parser.add_argument("--frames", default="1-12")
    parser.add_argument("--skip-replay", action="store_true")
    parser.add_argument("--gpu-frames", default="200-259")
    parser.add_argument("--skip-gpu-frame", action="store_true")
    args = parser.parse_args(argv)
    from ..benchmarks import selection
    print("Selection heuristic (benchmarks/selection.py)")
    selection.run()
    selection.run_benefit()
    try:
        from ..benchmarks import trace
    except ImportError:
        trace = None
    if trace is not None:
        print("\nTrace stage vs raw embreex (benchmarks/trace.py)")
        trace.run()
    if not args.skip_replay:
        replay_bench(args.scene, args.frames)
    if not args.skip_gpu_frame:
        gpu_frame_bench(args.gpu_frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
