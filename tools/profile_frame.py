"""Where a frame's time goes: median wall and calling-thread CPU ms of the GPU frame's steps
over a replay, and the run's stage means (what the cost model sees).

    .venv/bin/python tools/profile_frame.py arcade                     # RASTER, frames 200-239
    .venv/bin/python tools/profile_frame.py atrium --mode HYBRID --budget-ms 160
    .venv/bin/python tools/profile_frame.py atrium --mode HYBRID --budget-ms 128 --selection benefit \
        --frames 1-60 --resolution 320x240      # select_ms and readback_ms of BENEFIT

A/B against another checkout: make a directory holding a link named ``phrt`` to it and put
that directory first on PYTHONPATH (``PYTHONPATH=/tmp/base .venv/bin/python tools/...``);
run the two alternately, several times: this kind of machine varies by tens of percent.
Wall > CPU in a step means its thread waited (for llvmpipe's rasterizer threads)."""
from __future__ import annotations

import argparse
import importlib
import statistics
import tempfile
import time
from pathlib import Path

# (module of engine/gpu, attribute, label): GPUFrame's protocol methods and the passes they run.
STEPS = (("frame", "GPUFrame.draw", "draw"), ("gbuffer", "draw", "gbuffer.draw"),
         ("gbuffer", "resolve", "gbuffer.resolve"), ("frame", "GPUFrame.gbuffer", "gbuffer"),
         ("frame", "GPUFrame.shade", "shade"), ("lighting", "light", "lighting.light"),
         ("composite", "composite", "composite"))


def replay_scene(scene_name, mode, frames, width, height, budget_ms=None, overrides=None, keep=None):
    """Replay ``frames`` of a sample scene's camera path at ``width`` x ``height`` in a temporary
    run folder; returns (scene label, ``keep(result)`` before the folder goes, or the result)."""
    from phrt.cli import blender_process
    from phrt.engine.runs import camera_path, replay
    blender_process.blender()
    import bpy
    label = blender_process.load_scene(scene_name)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
    camera = camera_path.find_path(scene, None)
    frame_range = camera_path.parse_frames(frames, camera_path.path_frame_range(scene, camera))
    with tempfile.TemporaryDirectory() as temp:
        with blender_process.quiet_stdout():
            result = replay.replay(scene, camera, frame_range, mode.upper(), Path(temp) / "run", images="none",
                                   scene_label=label, budget_ms=budget_ms, overrides=overrides)
        return label, (keep(result) if keep else result)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene")
    parser.add_argument("--mode", default="RASTER")
    parser.add_argument("--frames", default="200-239")
    parser.add_argument("--budget-ms", type=float, default=None)
    parser.add_argument("--resolution", default="640x480")
    parser.add_argument("--selection", default=None, help="paper or benefit (default: the scene's)")
    args = parser.parse_args(argv)
    from phrt.cli import bench
    timings = {}

    def timed(name, function):
        def wrapper(*a, **k):
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                return function(*a, **k)
            finally:
                timings.setdefault(name, []).append(((time.perf_counter() - wall) * 1000.0,
                                                     (time.thread_time() - cpu) * 1000.0))
        return wrapper

    for module_name, attribute, label in STEPS:
        owner = importlib.import_module(f"phrt.engine.gpu.{module_name}")
        *path, name = attribute.split(".")
        for part in path:
            owner = getattr(owner, part)
        setattr(owner, name, timed(label, getattr(owner, name)))
    width, height = (int(v) for v in args.resolution.lower().split("x"))
    label, rows = replay_scene(args.scene, args.mode, args.frames, width, height, args.budget_ms,
                               {"selection": args.selection.upper()} if args.selection else None,
                               keep=lambda result: bench.steady_rows(result.run_dir))
    print(f"{label} {args.mode.upper()} frames {args.frames} at {width}x{height}: medians over frames 4+ "
          f"(wall / calling-thread CPU ms)")
    for _, _, step in STEPS:
        values = timings.get(step, [])[3:]
        if values:
            print(f"  {step:>15} {statistics.median(v[0] for v in values):7.1f} / "
                  f"{statistics.median(v[1] for v in values):6.1f}  ({len(values)} calls)")
    print("run means (frames 2+, one-time work out):", ", ".join(
        f"{key[:-3]} {bench.column_mean(rows, key):.1f}" for key in
        ("total_ms", "wall_ms", "gbuffer_ms", "composite_ms", "select_ms", "trace_ms", "readback_ms")))
    print("run medians (frames 2+):", ", ".join(
        f"{key[:-3]} {statistics.median(float(row[key]) for row in rows):.1f}" for key in
        ("total_ms", "select_ms", "trace_ms", "readback_ms")))
    totals = [row["total_ms"] for row in rows]
    if args.budget_ms:
        print(f"budget {args.budget_ms:.1f}: mean {statistics.mean(totals) / args.budget_ms:.3f}x, "
              f"p95 {bench.column_p95(rows, 'total_ms') / args.budget_ms:.3f}x")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
