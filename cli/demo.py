"""``make demo``: what PHRT does, in a few minutes on a 2-core machine without a GPU.

1. Renders one frame of a small scene built in code (floor, red cube, mirror
   sphere, glass slab, fence, sun and lamp) in hybrid mode, its budget 40% of the
   way from raster to ray traced time on this machine, and writes
   ``out/demo/showcase.png`` and a multilayer ``showcase.exr`` with every pass.
2. Builds the sample scenes if needed and runs a short sweep of the ``arcade``
   scene's ``path1`` (``phrt sweep``: raster, raytrace, then hybrid at 3 budgets
   between them in the variants of :data:`DEMO_VARIANTS` this checkout has,
   and the oracle on every 4th frame: 12 judged frames per run, enough for a
   captured share's interval to mean something; the hybrid runs in lockstep, frame
   by frame together, so that the variants meet the machine in the same state), each run a
   docs/formats.md run directory under ``out/demo/``, and the report
   (section 5, with the error-time curve, Table II, regret and popping) in
   ``out/demo/report/``.

    python -m phrt.cli.demo [--out out/demo] [--scene arcade] [--path path1] [--frames 1-48]
                        [--resolution 320x240] [--budgets 3]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

# The demo's sweep: short and small enough for 10 minutes on 2 cores (14 runs and the oracle on 12
# frames).  The variants: the paper's heuristic, the error-aware relevance, the benefit-per-ms
# selection and it with quality tiers (when present); the others (papercost, i0, i0.1, rperms) did
# not earn their demo time.
DEMO_FRAMES = "1-48"
DEMO_ORACLE_EVERY = 4
DEMO_VARIANTS = ("measured", "error", "benefit", "tiers")
DEMO_RESOLUTION = "320x240"
DEMO_BUDGETS = 3
SHOWCASE_BUDGET_AT = 0.4


def _render_showcase(bpy, out: Path):
    from .. import compat
    from ..engine import session
    from ..sample_scenes import showcase
    scene = showcase.build_showcase(640, 480)
    scene.phrt.mode = "HYBRID"
    scene.phrt.use_budget_at = True
    scene.phrt.budget_at = SHOWCASE_BUDGET_AT
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
        timings.append(dict(session.last_frame().stats))
    stats = timings[-1]  # the warm frame
    return (f"showcase frame (640x480, hybrid, budget at {SHOWCASE_BUDGET_AT:g} = {stats['budget_ms']:.0f} ms, warm): "
            f"total {stats['total_ms']:.0f} ms = raster {stats['raster_ms']:.0f}"
            f" + select {stats['select_ms']:.0f} + trace {stats['trace_ms']:.0f} + composite "
            f"{stats['composite_ms']:.0f} ms; {stats['n_selected']}/{stats['n_visible']} elements traced, "
            f"{stats['rays']} rays\n  wrote {out / 'showcase.png'} and {out / 'showcase.exr'}")


def main(argv=None):
    parser = argparse.ArgumentParser(description="PHRT demo")
    parser.add_argument("--out", default="out/demo")
    parser.add_argument("--scene", default="arcade")
    parser.add_argument("--path", default="path1")
    parser.add_argument("--frames", default=DEMO_FRAMES)
    parser.add_argument("--resolution", default=DEMO_RESOLUTION, help=f"WxH (default {DEMO_RESOLUTION})")
    parser.add_argument("--budgets", default=DEMO_BUDGETS, type=int)
    args = parser.parse_args(argv)
    started = time.perf_counter()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    from .. import cli
    from . import blender_process
    bpy = blender_process.blender()
    with blender_process.quiet_stdout():
        line = _render_showcase(bpy, out)
    print(line, flush=True)

    from ..phrt_addon.runs import plan
    variants = ",".join(name for name in DEMO_VARIANTS if name in plan.VARIANTS)
    status = cli.main(["sweep", args.scene, "--path", args.path, "--frames", args.frames, "--budgets",
                       str(args.budgets), "--resolution", args.resolution, "--out", str(out),
                       "--variants", variants, "--oracle-every", str(DEMO_ORACLE_EVERY), "--lockstep"])
    print(f"report: {out / 'report' / 'report.md'}  {out / 'report' / 'report.html'}")
    print(f"demo finished in {time.perf_counter() - started:.0f} s")
    return status


if __name__ == "__main__":
    sys.exit(main())
