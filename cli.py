"""The ``phrt`` command: build sample scenes, replay camera paths, write reports.

    phrt scenes [--out DIR]
    phrt render SCENE [--path NAME] [--frames A-B] [--mode raster|hybrid|raytrace]
                      [--budget-ms T] [--resolution WxH] [--out DIR] [--images exr|png|none]
    phrt report RUN_DIR... [--reference RUN_DIR] [--out DIR]

Runs Blender as the ``bpy`` module with the PHRT add-on registered from this
package; ``render`` goes through the same replay code as the
``phrt.replay_path`` operator, so both write the same files.  Bad input exits
with status 2 and one line ``phrt: error: ...`` on stderr; everything is
checked before anything is written.
"""
from __future__ import annotations

import argparse
import contextlib
import math
import os
import signal
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent
SAMPLE_DIR = ROOT / "sample_scenes"


class UserError(Exception):
    """Bad input: printed as one line, exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UserError(message)


def build_parser():
    parser = _Parser(prog="phrt", description="PHRT hybrid renderer: replays camera paths in raster, hybrid "
                                              "and ray traced modes and reports error against run time.")
    commands = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    scenes = commands.add_parser("scenes", help="build the sample scenes (.blend files)")
    scenes.add_argument("--out", default=str(SAMPLE_DIR), help="folder for the .blend files (default: sample_scenes/)")
    render = commands.add_parser("render", help="replay a camera path of a scene")
    render.add_argument("scene", help="a .blend file or a sample scene name (arcade, atrium)")
    render.add_argument("--path", help="camera path (camera object) to replay (default: the scene's first)")
    render.add_argument("--frames", help="frame range A-B (default: the whole path)")
    render.add_argument("--mode", default="hybrid", type=str.lower, help="raster, hybrid or raytrace")
    render.add_argument("--budget-ms", type=_number, help="frame time budget in ms (default: the scene's)")
    render.add_argument("--resolution", help="WxH in pixels (default: the scene's)")
    render.add_argument("--out", help="run directory (default: out/<scene>-<path>-<mode>/)")
    render.add_argument("--images", default="exr", type=str.lower, help="exr, png or none")
    report = commands.add_parser("report", help="error against run time for runs of the same path")
    report.add_argument("runs", nargs="+", metavar="RUN_DIR")
    report.add_argument("--reference", help="reference run (default: the raytrace run among RUN_DIRs)")
    report.add_argument("--out", default="out/report", help="report folder (default: out/report)")
    return parser


def _number(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"'{text}' is not a finite number")
    return value


def parse_resolution(text):
    if text is None:
        return None
    parts = text.lower().split("x")
    try:
        width, height = (int(p) for p in parts)
    except ValueError:
        raise UserError(f"malformed resolution '{text}': use WxH, e.g. --resolution 640x480") from None
    if width <= 0 or height <= 0 or width > 16384 or height > 16384:
        raise UserError(f"resolution '{text}' is out of range: width and height must be 1-16384 pixels")
    return width, height


def _check_output_dir(path):
    """Raise UserError unless ``path`` can be created and written (creates nothing)."""
    from .phrt_addon.runlog import output_dir_problem
    problem = output_dir_problem(path)
    if problem is not None:
        raise UserError(problem)


def _progress(stream):
    """A progress printer for a terminal; silent otherwise."""
    if not stream.isatty():
        return None
    started = time.perf_counter()

    def show(done, total, frame_ms):
        elapsed = time.perf_counter() - started
        eta = elapsed / done * (total - done)
        stream.write(f"\r  frame {done}/{total}  {frame_ms:6.0f} ms/frame  ETA {eta:5.0f} s ")
        stream.flush()
        if done == total:
            stream.write("\n")
    return show


@contextlib.contextmanager
def _quiet_stdout():
    """Blender prints 'Saved: ...' per frame on stdout; keep stdout for our summary lines."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    try:
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(devnull)
        os.close(saved)


def _blender():
    """Import bpy and register the add-on from this package (idempotent)."""
    import bpy
    from . import register
    if not hasattr(bpy.types.Scene, "phrt"):
        register()
    return bpy


def _sample_is_stale(blend_path):
    """A sample .blend is rebuilt when missing or older than any of its generator's modules."""
    if not blend_path.exists():
        return True
    built = blend_path.stat().st_mtime
    return any(module.stat().st_mtime > built for module in SAMPLE_DIR.glob("*.py"))


def load_scene(name_or_path):
    """Open a .blend file or a sample scene by name (built on first use); returns the scene's label."""
    from .sample_scenes import generate
    path = Path(name_or_path)
    if path.suffix.lower() != ".blend" and name_or_path in generate.SCENES:
        path = SAMPLE_DIR / f"{name_or_path}.blend"
        bpy = _blender()
        if _sample_is_stale(path):
            with _quiet_stdout():
                generate.write_scene(name_or_path, SAMPLE_DIR)
        bpy.ops.wm.open_mainfile(filepath=str(path))
        return name_or_path
    if not path.exists():
        raise UserError(f"no such file or sample scene '{name_or_path}': give a .blend file or one of "
                        f"{', '.join(generate.SCENES)}")
    if path.is_dir() or path.suffix.lower() != ".blend":
        raise UserError(f"'{name_or_path}' is not a .blend file")
    with open(path, "rb") as handle:
        magic = handle.read(7)
    if magic not in (b"BLENDER",) and not magic.startswith(b"\x1f\x8b") and not magic.startswith(b"\x28\xb5\x2f\xfd"):
        raise UserError(f"'{name_or_path}' is not a valid .blend file (bad header)")
    bpy = _blender()
    try:
        with _quiet_stdout():
            bpy.ops.wm.open_mainfile(filepath=str(path.resolve()))
    except RuntimeError as error:
        raise UserError(f"cannot open '{name_or_path}': {str(error).strip().splitlines()[-1]}") from None
    return path.stem


def command_scenes(args):
    _check_output_dir(args.out)
    _blender()
    from .sample_scenes import generate
    for name in generate.SCENES:
        start = time.perf_counter()
        with _quiet_stdout():
            path = generate.write_scene(name, args.out)
        print(f"{name}: {path} ({time.perf_counter() - start:.1f} s)")
    return 0


def command_render(args):
    from .engine import replay as replay_module  # noqa: F401  (imports bpy)
    if args.mode not in ("raster", "hybrid", "raytrace"):
        raise UserError(f"unknown mode '{args.mode}': use raster, hybrid or raytrace")
    if args.images not in ("exr", "png", "none"):
        raise UserError(f"unknown image format '{args.images}': use exr, png or none")
    if args.budget_ms is not None and args.budget_ms < 0:
        raise UserError(f"negative budget {args.budget_ms:g} ms: give --budget-ms a value >= 0")
    resolution = parse_resolution(args.resolution)
    if args.frames is not None:
        try:
            replay_module.parse_frames(args.frames, (1, 1))  # syntax check before loading anything
        except replay_module.ReplayError as error:
            raise UserError(str(error)) from None
    if args.out is not None:
        _check_output_dir(args.out)
    label = load_scene(args.scene)
    import bpy
    scene = bpy.context.scene
    try:
        camera = replay_module.find_path(scene, args.path)
        frame_range = replay_module.parse_frames(args.frames, replay_module.path_frame_range(scene, camera))
    except replay_module.ReplayError as error:
        raise UserError(str(error)) from None
    out = Path(args.out) if args.out else replay_module.default_run_dir("out", label, camera.name, args.mode)
    _check_output_dir(out)
    progress = _progress(sys.stderr)
    started = time.perf_counter()
    try:
        with _quiet_stdout():
            result = replay_module.replay(scene, camera, frame_range, args.mode, out, images=args.images,
                                          budget_ms=args.budget_ms, resolution=resolution, scene_label=label,
                                          on_progress=progress)
    except replay_module.ReplayError as error:
        raise UserError(str(error)) from None
    for line in result.problems:  # each problem of the scene once, with its count
        print(f"phrt: warning: {line}", file=sys.stderr)
    if result.signal:
        print(f"phrt: interrupted by {result.signal}: {result.frames_done} of {frame_range[1] - frame_range[0] + 1} "
              f"frames written to {out} (summary.json says partial)", file=sys.stderr)
        return 128 + int(getattr(signal, result.signal))
    summary = result.summary or {}
    total = summary.get("total_ms", {})
    print(f"phrt: {label}/{camera.name} {args.mode}: {result.frames_done} frames in "
          f"{time.perf_counter() - started:.1f} s, mean {total.get('mean', float('nan')):.0f} ms/frame "
          f"(p95 {total.get('p95', float('nan')):.0f}), budget {summary.get('budget_ms', 0):g} ms -> {out}")
    return 0


def command_report(args):
    from .phrt_addon import report
    for run in list(args.runs) + ([args.reference] if args.reference else []):
        if not Path(run).is_dir():
            raise UserError(f"no run directory '{run}': give folders written by 'phrt render'")
        if not (Path(run) / "frames.csv").exists():
            raise UserError(f"'{run}' is not a run directory (no frames.csv): give folders written by 'phrt render'")
    _check_output_dir(args.out)
    try:
        files = report.build_report(args.runs, reference=args.reference, out_dir=args.out)
    except (ValueError, FileNotFoundError) as error:
        raise UserError(str(error).splitlines()[0]) from None
    print(f"phrt: report {files.markdown} and {files.html}")
    return 0


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    try:
        args = build_parser().parse_args(argv)
        command = {"scenes": command_scenes, "render": command_render, "report": command_report}[args.command]
        return command(args)
    except UserError as error:
        print(f"phrt: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
