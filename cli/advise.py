"""``phrt advise SCENE [--path NAME] [--frames A-B] [--budget-at F,F...] [--resolution WxH] [--out DIR]``:
what each tag is worth per millisecond along a camera path, and one recommendation per
(element, effect) item (docs/advice.md).  Bad input exits 2 with one line, like ``phrt render``;
everything is checked before anything is written."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from .arguments import budget_fractions, check_output_dir, parse_resolution
from .blender_process import UserError, load_scene, quiet_stdout


def add_parser(commands):
    advise = commands.add_parser("advise", help="what each ray tracing tag is worth per ms along a camera path")
    advise.add_argument("scene", help="a .blend file or a sample scene name (arcade, atrium)")
    advise.add_argument("--path", help="camera path (camera object) to judge (default: the scene's first)")
    advise.add_argument("--frames", help="frame range A-B (default: the whole path)")
    advise.add_argument("--budget-at", default="0.25,0.5,0.75", metavar="F[,F...]",
                        help="budgets as fractions of the way from raster (0) to ray traced (1) frame time "
                             "(default 0.25,0.5,0.75)")
    advise.add_argument("--resolution", help="WxH in pixels (default: the scene's)")
    advise.add_argument("--out", help="advice folder (default: out/<scene>-<path>-advice/)")
    advise.add_argument("--every", default=None, metavar="K", help="judge every K-th frame (default 4)")
    advise.add_argument("--untagged", default=None, metavar="N",
                        help="judge at most the N most promising untagged objects (default 8)")
    return advise


def _whole(text, name, default):
    if text is None:
        return default
    try:
        value = int(text)
    except ValueError:
        raise UserError(f"{name} '{text}' is not a whole number") from None
    if value < (1 if name == "--every" else 0):
        raise UserError(f"{name} {value} is out of range: give a count >= {1 if name == '--every' else 0}")
    return value


def command_advise(args):
    from ..engine.runs import advise
    from ..engine.runs import camera_path
    from ..phrt_addon.advise import items
    fractions = tuple(budget_fractions(args.budget_at))
    every = _whole(args.every, "--every", advise.DEFAULT_EVERY)
    cap = _whole(args.untagged, "--untagged", items.DEFAULT_PROSPECTS)
    resolution = parse_resolution(args.resolution)
    if args.frames is not None:
        try:
            camera_path.parse_frames(args.frames, (1, 1))
        except camera_path.ReplayError as error:
            raise UserError(str(error)) from None
    if args.out:
        check_output_dir(args.out)
    label = load_scene(args.scene)
    import bpy
    scene = bpy.context.scene
    try:
        camera = camera_path.find_path(scene, args.path)
        frame_range = camera_path.parse_frames(args.frames, camera_path.path_frame_range(scene, camera))
    except camera_path.ReplayError as error:
        raise UserError(str(error)) from None
    out = Path(args.out) if args.out else Path("out") / f"{label}-{camera.name}-advice"
    check_output_dir(out)
    started = time.perf_counter()
    stream = sys.stderr

    def show(done, total, what):
        if stream.isatty():
            stream.write(f"\r  {done}/{total} {what:<32} {time.perf_counter() - started:6.0f} s ")
            stream.flush()

    try:
        with quiet_stdout():
            written = advise.run_advice(scene, camera, frame_range, out, budget_at=fractions, every=every,
                                        prospects_cap=cap, resolution=resolution, scene_label=label,
                                        on_progress=show)
    except (camera_path.ReplayError, ValueError) as error:
        raise UserError(str(error).splitlines()[0]) from None
    if stream.isatty():
        stream.write("\n")
    import json
    document = json.loads(Path(written["json"]).read_text(encoding="utf-8"))
    counts = {}
    for item in document["items"]:
        counts[item["recommendation"]] = counts.get(item["recommendation"], 0) + 1
    print(f"phrt: {label}/{camera.name} advice: {len(document['items'])} items over {document['judged_frames']} "
          f"judged frames in {time.perf_counter() - started:.0f} s "
          f"({document['seconds_per_judged_frame']:.1f} s per judged frame): "
          + ", ".join(f"{name} {count}" for name, count in sorted(counts.items())) + f" -> {out}")
    return 0

