"""The ``phrt`` command: build sample scenes, replay camera paths, write reports.

    phrt scenes [--out DIR]
    phrt render SCENE [--path NAME] [--frames A-B] [--mode raster|hybrid|raytrace]
                      [--budget-ms T] [--resolution WxH] [--out DIR] [--images exr|png|none] [--overwrite]
                      [--selection paper|benefit]
    phrt report RUN_DIR... [--reference RUN_DIR] [--out DIR]
    phrt sweep SCENE [--path NAME] [--frames A-B] [--budgets N | --budget-at F[,F...]] [--lockstep]
                     [--resolution WxH] [--out DIR] [--oracle-every K] [--variants NAME,...]
                     [--selection paper|benefit]
                     [--workers N [--dashboard ADDRESS] | --scheduler ADDRESS [--tls-ca-file F
                     --tls-cert F --tls-key F]]
    phrt rescore SWEEP_DIR [--out DIR]
    phrt advise SCENE [--path NAME] [--frames A-B] [--budget-at F,F...] [--resolution WxH] [--out DIR]

Runs Blender as the ``bpy`` module with the PHRT add-on registered from this
package; ``render`` goes through the same replay code as the
``phrt.replay_path`` operator, so both write the same files.  Bad input exits
with status 2 and one line ``phrt: error: ...`` on stderr; everything is
checked before anything is written.
"""
from __future__ import annotations

import argparse
import signal
import sys
import time
from pathlib import Path

from . import blender_process
from .arguments import budget_fractions, check_output_dir, check_replay_input, count, number, parse_resolution
from .blender_process import SAMPLE_DIR, UserError, load_scene
from ..phrt_addon.schema import SELECTIONS
from . import advise as advise_command
from .rescore import command_rescore


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
    render.add_argument("--budget-ms", type=number, help="frame time budget in ms (default: the scene's)")
    render.add_argument("--budget-at", type=number, metavar="F",
                        help="frame time budget F of the way from raster (0) to ray traced (1) frame time on "
                             "this machine, from runs of the path beside --out or a short calibration")
    render.add_argument("--resolution", help="WxH in pixels (default: the scene's)")
    render.add_argument("--out", help="run directory (default: out/<scene>-<path>-<mode>/)")
    render.add_argument("--images", default="exr", type=str.lower, help="exr, png or none")
    render.add_argument("--selection", type=str.lower, choices=SELECTIONS,
                        help="what the hybrid frames trace: paper (the paper's heuristic) or benefit (the "
                             "benefit-per-ms items); default the scene's setting")
    render.add_argument("--overwrite", action="store_true",
                        help="replace the run --out holds (its files are removed first); without it such a folder "
                             "is refused")
    report = commands.add_parser("report", help="error against run time for runs of the same path")
    report.add_argument("runs", nargs="+", metavar="RUN_DIR")
    report.add_argument("--reference", help="reference run (default: the raytrace run among RUN_DIRs)")
    report.add_argument("--out", default="out/report", help="report folder (default: out/report)")
    rescore = commands.add_parser("rescore", help="judge a sweep's recorded choices again on its oracle's "
                                                  "measurements, without rendering")
    rescore.add_argument("sweep_dir", metavar="SWEEP_DIR")
    rescore.add_argument("--out", help="folder for rescore.csv and rescore.md (default: SWEEP_DIR/report)")
    sweep = commands.add_parser("sweep", help="error against run time: raster, raytrace and hybrid at N budgets")
    sweep.add_argument("scene", help="a .blend file or a sample scene name (arcade, atrium)")
    sweep.add_argument("--path", help="camera path (camera object) to replay (default: the scene's first)")
    sweep.add_argument("--frames", help="frame range A-B (default: the whole path)")
    sweep.add_argument("--budgets", type=count, default=None,
                       help="hybrid budgets spread evenly between raster and ray traced frame time (default 5)")
    sweep.add_argument("--budget-at", metavar="F[,F...]",
                       help="the hybrid budgets as fractions of the way from raster (0) to ray traced (1) frame "
                            "time, instead of --budgets")
    sweep.add_argument("--resolution", help="WxH in pixels (default: the scene's)")
    sweep.add_argument("--out", help="sweep folder (default: out/<scene>-<path>-sweep/)")
    sweep.add_argument("--oracle-every", type=count, default=None, metavar="K",
                       help="the oracle judges every K-th frame (default 8)")
    sweep.add_argument("--selection", type=str.lower, choices=SELECTIONS,
                       help="the selection of every variant that does not choose its own (default paper; "
                            "the benefit variant is always benefit)")
    sweep.add_argument("--variants", metavar="NAME[,NAME...]",
                       help="selection variants of the hybrid runs (default all: measured, papercost, i0, i0.1, "
                            "rperms, error)")
    sweep.add_argument("--lockstep", action="store_true",
                       help="render the hybrid runs of the path together, frame by frame, so that every budget and "
                            "variant meets the machine in the same state (a comparison free of the machine's drift "
                            "between runs; in this process, not with --workers or --scheduler)")
    sweep.add_argument("--workers", type=count, default=None, metavar="N",
                       help="run the plan on a Dask LocalCluster of N worker processes on this machine "
                            "(default: one run after the other in this process)")
    sweep.add_argument("--scheduler", metavar="ADDRESS",
                       help="run the plan on the existing Dask cluster whose scheduler is at ADDRESS "
                            "(tcp://HOST:8786); its workers need --resources phrt=1 and the sweep folder "
                            "(docs/cluster.md)")
    sweep.add_argument("--dashboard", metavar="ADDRESS", default=None,
                       help="where the LocalCluster of --workers serves its Dask dashboard (default 127.0.0.1:8787, "
                            "this machine only; e.g. 0.0.0.0:8787 shows task names, paths and logs to the network)")
    for flag, what in (("--tls-ca-file", "CA certificate(s)"), ("--tls-cert", "this client's certificate"),
                       ("--tls-key", "this client's private key")):
        sweep.add_argument(flag, metavar="FILE", help=f"{what} (PEM) for a tls:// --scheduler (docs/cluster.md)")
    advise_command.add_parser(commands)
    return parser


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


def command_scenes(args):
    check_output_dir(args.out)
    blender_process.blender()
    from ..sample_scenes import generate
    for name in generate.SCENES:
        start = time.perf_counter()
        with blender_process.quiet_stdout():
            path = generate.write_scene(name, args.out)
        print(f"{name}: {path} ({time.perf_counter() - start:.1f} s)")
    return 0


def _open_path(args):
    """The replay arguments every command that renders a path shares: the frame range's syntax and
    the output folder are checked before anything is loaded, then the scene is opened and its
    camera path and frame range found.  Returns (label, scene, camera, frame range)."""
    from ..engine.runs import camera_path
    if args.frames is not None:
        try:
            camera_path.parse_frames(args.frames, (1, 1))  # syntax check before loading anything
        except camera_path.ReplayError as error:
            raise UserError(str(error)) from None
    if args.out is not None:
        check_output_dir(args.out)
    label = load_scene(args.scene)
    import bpy
    scene = bpy.context.scene
    try:
        camera = camera_path.find_path(scene, args.path)
        frame_range = camera_path.parse_frames(args.frames, camera_path.path_frame_range(scene, camera))
    except camera_path.ReplayError as error:
        raise UserError(str(error)) from None
    return label, scene, camera, frame_range


def command_render(args):
    from ..engine.runs import replay as replay_module
    from ..engine.runs import camera_path
    check_replay_input(mode=args.mode, images=args.images, budget_ms=args.budget_ms, budget_at=args.budget_at)
    if args.budget_ms is not None and args.budget_at is not None:
        raise UserError("--budget-ms and --budget-at both given: give the budget one way")
    resolution = parse_resolution(args.resolution)
    label, scene, camera, frame_range = _open_path(args)
    out = Path(args.out) if args.out else replay_module.default_run_dir("out", label, camera.name, args.mode)
    check_output_dir(out)
    progress = _progress(sys.stderr)
    started = time.perf_counter()
    try:
        with blender_process.quiet_stdout():
            result = replay_module.replay(scene, camera, frame_range, args.mode, out, images=args.images,
                                          budget_ms=args.budget_ms, resolution=resolution, scene_label=label,
                                          on_progress=progress, budget_at=args.budget_at,
                                          overwrite=args.overwrite,
                                          overrides={"selection": args.selection.upper()} if args.selection else None)
    except camera_path.ReplayError as error:
        raise UserError(str(error)) from None
    for line in result.problems:  # each problem of the scene once, with its count
        print(f"phrt: warning: {line}", file=sys.stderr)
    if result.signal:
        print(f"phrt: interrupted by {result.signal}: {result.frames_done} of {frame_range[1] - frame_range[0] + 1} "
              f"frames written to {out} (summary.json says partial)", file=sys.stderr)
        return 128 + int(getattr(signal, result.signal))
    summary = result.summary or {}
    total = summary.get("total_ms", {})
    source = summary.get("budget_source")
    if source:
        print(f"phrt: budget at {source['budget_at']:g} = {source['budget_ms']:.0f} ms (raster {source['raster_ms']:.0f}"
              f" ms, ray traced {source['raytrace_ms']:.0f} ms, from {source['method']})")
    print(f"phrt: {label}/{camera.name} {args.mode}: {result.frames_done} frames in "
          f"{time.perf_counter() - started:.1f} s, mean {total.get('mean', float('nan')):.0f} ms/frame "
          f"(p95 {total.get('p95', float('nan')):.0f}), budget {summary.get('budget_ms', 0):g} ms -> {out}")
    return 0


def command_report(args):
    from ..phrt_addon import report
    for run in list(args.runs) + ([args.reference] if args.reference else []):
        if not Path(run).is_dir():
            raise UserError(f"no run directory '{run}': give folders written by 'phrt render'")
        if not (Path(run) / "frames.csv").exists():
            raise UserError(f"'{run}' is not a run directory (no frames.csv): give folders written by 'phrt render'")
    check_output_dir(args.out)
    try:
        files = report.build_report(args.runs, reference=args.reference, out_dir=args.out)
    except (ValueError, FileNotFoundError) as error:
        raise UserError(str(error).splitlines()[0]) from None
    except OSError as error:  # a full disk, a read-only or vanished folder
        raise UserError(f"cannot write the report to '{args.out}': {error.strerror or error}") from None
    print(f"phrt: report {files.markdown} and {files.html}")
    return 0


def _sweep_fractions(args):
    """The sweep's budget fractions from --budget-at or --budgets (UserError if both or malformed)."""
    from ..phrt_addon.runs import plan as plan_module
    if args.budget_at is not None and args.budgets is not None:
        raise UserError("--budgets and --budget-at both given: give the hybrid budgets one way")
    if args.budget_at is None:
        return plan_module.budget_fractions(args.budgets or plan_module.DEFAULT_BUDGETS)
    return budget_fractions(args.budget_at)


def command_sweep(args):
    if args.lockstep and (args.workers is not None or args.scheduler is not None):
        raise UserError("--lockstep renders the hybrid runs together in this process: not with --workers or "
                        "--scheduler")
    from ..phrt_addon.report import oracle as oracle_module
    from ..phrt_addon.runs import plan as plan_module
    from . import cluster
    cluster_options = cluster.executor_options(args)
    fractions = _sweep_fractions(args)
    variants = tuple(plan_module.VARIANTS)
    if args.variants is not None:
        variants = tuple(dict.fromkeys(name.strip() for name in args.variants.split(",") if name.strip()))
        unknown = [name for name in variants if name not in plan_module.VARIANTS]
        if unknown or not variants:
            raise UserError(f"unknown selection variant(s) {', '.join(unknown) or repr(args.variants)}: use some of "
                            f"{', '.join(plan_module.VARIANTS)}")
    resolution = parse_resolution(args.resolution)
    label, scene, camera, frame_range = _open_path(args)
    from ..engine import extract
    resolution = resolution or extract.resolution(scene)
    folder = Path(args.out) if args.out else Path("out") / f"{label}-{camera.name}-sweep"
    check_output_dir(folder)
    scene_ref = args.scene if Path(args.scene).suffix.lower() != ".blend" else str(Path(args.scene).resolve())
    from ..phrt_addon.raster import gbuffer
    problem = gbuffer.resolution_problem(*resolution)
    if problem is not None:
        raise UserError(problem)
    try:
        plan = plan_module.build_plan(scene_ref, label, camera.name, frame_range, resolution, fractions, variants,
                                      oracle_every=args.oracle_every or oracle_module.DEFAULT_EVERY,
                                      selection=args.selection, group_raster=args.lockstep)
    except plan_module.PlanError as error:
        raise UserError(str(error)) from None
    if args.lockstep:
        from .lockstep import LockstepExecutor
        executor = LockstepExecutor()
    else:
        executor = cluster.start_executor(args.workers, args.scheduler, cluster_options)
    try:
        return _run_sweep(plan, folder, label, camera.name, frame_range, resolution, executor)
    finally:
        cluster.close_executor(executor)


def _run_sweep(plan, folder, label, camera_name, frame_range, resolution, executor):
    from . import sweep as sweep_engine
    from ..phrt_addon.runs import executors
    from ..phrt_addon.runs import progress as run_progress
    from ..phrt_addon.runs import plan as plan_module
    try:
        plan_path = plan_module.write_plan(plan, folder)
    except OSError as error:
        raise UserError(f"cannot write the plan to '{folder}': {error.strerror or error}") from None
    started = time.perf_counter()
    total = len(plan.jobs)
    print(f"phrt: sweep of {label}/{camera_name} frames {frame_range[0]}-{frame_range[1]} at "
          f"{resolution[0]}x{resolution[1]}: {len(plan.runs)} runs and the oracle -> {plan_path}", flush=True)
    progress = run_progress.Progress(total, sys.stderr)
    counter = [0]
    if hasattr(executor, "on_frame"):  # a lockstep group: its frames on the progress line
        executor.on_frame = lambda done, frames, runs: progress.under_way(
            f"{runs} runs in lockstep, frame {done}/{frames}")

    def show(outcome):
        counter[0] += 1
        line = f"phrt: [{counter[0]}/{total}] {outcome.job_id}: {outcome.status}"
        if outcome.status == "done":
            line += f" in {outcome.seconds:.1f} s"
            line += f" on {outcome.worker}" if outcome.worker else ""
            line += f" ({outcome.message})"
        elif outcome.message and outcome.status == "failed":
            line += f": {outcome.message}"
        progress.clear()
        print(line, file=sys.stderr if outcome.status == "failed" else sys.stdout, flush=True)
        progress.update(outcome)

    try:
        outcomes, files, no_report = sweep_engine.run_plan(plan_path, plan, executor, on_outcome=show)
    except (sweep_engine.SweepInterrupted, KeyboardInterrupt) as stop:
        # A signal during a run stops it between frames (SweepInterrupted); Ctrl-C elsewhere (the
        # oracle, a warm-up frame) raises KeyboardInterrupt: the job's temporary folder is gone.
        name = getattr(stop, "signal_name", "SIGINT")
        during = f" during {stop.job_id}" if hasattr(stop, "job_id") else ""
        progress.clear()
        complete = sum(plan_module.run_is_complete(folder / job.id, plan) for job in plan.runs)
        print(f"phrt: sweep interrupted by {name}{during}: {complete} of {len(plan.runs)} runs complete "
              f"are kept; run the same command again to resume", file=sys.stderr)
        return 128 + int(getattr(signal, name))
    except executors.ExecutorError as error:
        raise UserError(str(error)) from None
    except OSError as error:  # a full disk under the report
        raise UserError(f"cannot write the sweep's report in '{folder}': {error.strerror or error}") from None
    failed = [outcome for outcome in outcomes if outcome.status == "failed"]
    if files is not None:
        complete = sum(plan_module.run_is_complete(folder / job.id, plan) for job in plan.runs)
        print(f"phrt: sweep report {files.markdown} ({files.sweep_csv.name}, {files.error_vs_time_png.name}); "
              f"{complete} runs in {time.perf_counter() - started:.0f} s")
    else:
        print(f"phrt: no report: {no_report}", file=sys.stderr)
    if failed:
        print(f"phrt: {len(failed)} of {total} jobs failed: {', '.join(o.job_id for o in failed)}", file=sys.stderr)
        return 1
    return 0


def main(argv=None):
    """The ``phrt`` program (``argv`` None: ``sys.argv``, and the process ends here once Blender
    was loaded, see blender_process.end_program) or a call from Python (returns the exit code)."""
    as_program = argv is None  # the `phrt` program itself: its stdout ends with its last line
    argv = sys.argv[1:] if argv is None else argv
    try:
        code = _run(argv)
    except BaseException:
        if as_program and "bpy" in sys.modules:
            blender_process.quiet_exit()
        raise
    if as_program and "bpy" in sys.modules:
        blender_process.end_program(code or 0)
    return code


def _run(argv) -> int:
    try:
        args = build_parser().parse_args(argv)
        if args.command not in ("report", "rescore"):  # every other command runs Blender
            blender_process.import_blender()
        command = {"scenes": command_scenes, "render": command_render, "report": command_report,
                   "rescore": command_rescore, "sweep": command_sweep,
                   "advise": advise_command.command_advise}[args.command]
        return command(args)
    except UserError as error:
        print(f"phrt: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
