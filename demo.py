"""``make demo``: what PHRT does, in a few minutes on a 2-core machine without a GPU.

1. Renders one frame of a small scene built in code (floor, red cube, mirror
   sphere, glass slab, fence, sun and lamp) in hybrid mode and writes
   ``out/demo/showcase.png`` and a multilayer ``showcase.exr`` with every pass.
2. Builds the sample scenes if needed, replays the first frames of the
   ``arcade`` scene's ``path1`` in raster, hybrid and raytrace modes
   (CONTRACT.md section 4 run directories under ``out/demo/``), and writes the
   report (section 5) to ``out/demo/report/``.

    python -m phrt.demo [--out out/demo] [--scene arcade] [--path path1] [--frames 1-48]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


def _render_showcase(bpy, out: Path):
    from . import compat
    from .engine import final
    from .sample_scenes import showcase
    scene = showcase.build_showcase(640, 480)
    scene.phrt.mode = "HYBRID"
    scene.phrt.budget_ms = 1000.0
    render = scene.render
    settings = render.image_settings
    timings = []
    for image_format, suffix in (("PNG", "png"), ("EXR", "exr")):
        if image_format == "PNG":
            compat.set_image_format(settings, compat.PNG)
        else:
            compat.set_image_format(settings, compat.MULTILAYER_EXR)
            settings.color_depth = "32"
        render.use_file_extension = True
        render.filepath = str(out / "showcase")
        bpy.ops.render.render(write_still=True)
        timings.append(dict(final.LAST_FRAME["stats"]))
    stats = timings[-1]  # the warm frame
    return (f"showcase frame (640x480, hybrid, warm): total {stats['total_ms']:.0f} ms = raster {stats['raster_ms']:.0f}"
          f" + select {stats['select_ms']:.0f} + trace {stats['trace_ms']:.0f} + composite "
          f"{stats['composite_ms']:.0f} ms; {stats['n_selected']}/{stats['n_visible']} elements traced, "
          f"{stats['rays']} rays\n  wrote {out / 'showcase.png'} and {out / 'showcase.exr'}")


def main(argv=None):
    parser = argparse.ArgumentParser(description="PHRT demo")
    parser.add_argument("--out", default="out/demo")
    parser.add_argument("--scene", default="arcade")
    parser.add_argument("--path", default="path1")
    parser.add_argument("--frames", default="1-48")
    parser.add_argument("--resolution", default=None, help="WxH (default: the scene's, 640x480)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    from . import cli
    bpy = cli._blender()
    with cli._quiet_stdout():
        line = _render_showcase(bpy, out)
    print(line)

    from .engine import replay
    from .phrt_addon import report
    label = cli.load_scene(args.scene)
    scene = bpy.context.scene
    camera = replay.find_path(scene, args.path)
    frame_range = replay.parse_frames(args.frames, replay.path_frame_range(scene, camera))
    resolution = cli.parse_resolution(args.resolution)
    run_dirs = []
    for mode in ("RAYTRACE", "HYBRID", "RASTER"):
        run_dir = replay.default_run_dir(out, label, camera.name, mode)
        progress = cli._progress(sys.stderr)
        begin = time.perf_counter()
        with cli._quiet_stdout():
            result = replay.replay(scene, camera, frame_range, mode, run_dir, images="exr",
                                   resolution=resolution, scene_label=label, on_progress=progress)
        total = result.summary["total_ms"]
        print(f"{label}/{camera.name} {mode.lower():8s}: {result.frames_done} frames in "
              f"{time.perf_counter() - begin:5.1f} s, mean {total['mean']:.0f} ms/frame (p95 {total['p95']:.0f}), "
              f"budget {result.summary['budget_ms']:g} ms -> {run_dir}")
        run_dirs.append(run_dir)
    files = report.build_report(run_dirs, out_dir=out / "report")
    print(f"report: {files.markdown}  {files.html}")
    print(f"demo finished in {time.perf_counter() - started:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
