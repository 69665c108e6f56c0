"""A selection constant A/B'd in lockstep on one camera path: what fitting a constant on the
training paths, and judging it on the held-out ones, takes (docs/selection.md, "Fitting and
judging").

A raster and a ray traced run of the path first (the budgets at F of the way between them, and
the reference frames; reused when ``OUT`` has them complete), then one hybrid run per (budget at
F, value of the constant), all rendered frame by frame together (``phrt sweep --lockstep``'s
stepping: every run meets the machine in the same state), the constant set to the run's value
before each of its frames.  Per budget and value: the mean LDR-FLIP against the ray traced frames
(the first frame left out: one-time work), its difference relative to the first value's run on
the same frames, sum(run - baseline) / sum(baseline), with a 90% studentized moving-block
bootstrap interval over frames (``report.captured.ratio_interval``, the yardstick's own), "lower"
or "higher" only where the interval leaves out 0; p95 / budget, elements traced per frame and flips
per element per 100 frames.  Prints the table and writes ``OUT/constant_ab.csv``.

    python tools/constant_ab.py arcade --path path1 --frames 1-120 \\
        --constant benefit_selection.ADD_SLACK --values 0.25,0 [--budget-at 0.25,0.5] \\
        [--resolution 320x240] [--selection benefit] [--block N] [--out out/constant-ab/arcade-path1]

``--constant`` names a number in a module of ``phrt_addon/select`` that the selection reads when
it runs (a module constant, not one copied into an object at its creation); the first of
``--values`` is the baseline.  The scene is a sample scene's name or a .blend file.
"""
from __future__ import annotations

import argparse
import ast
import csv
import importlib
import shutil
import sys
from pathlib import Path

import numpy as np

COLUMNS = ("budget_at", "budget_ms", "value", "frames", "mean_flip", "difference", "low", "high", "verdict",
           "p95_over_budget", "selected_per_frame", "flips_per_100")


class UsageError(Exception):
    """Bad arguments: one line, exit 2."""


class RunFailed(Exception):
    """A run failed while rendering: one line, exit 1."""


def parse_constant(spec: str):
    """(module, attribute name) of ``module.NAME`` among ``phrt_addon.select``'s modules: a number
    the module itself assigns at its top level (one it imports from another module is read there,
    so setting it here would change nothing)."""
    module_name, _, name = spec.rpartition(".")
    if not module_name or not name:
        raise UsageError(f"--constant {spec!r}: give it as module.NAME, e.g. benefit_selection.ADD_SLACK")
    try:
        module = importlib.import_module(f"phrt.phrt_addon.select.{module_name}")
    except ImportError:
        raise UsageError(f"--constant {spec!r}: no module phrt_addon/select/{module_name}.py") from None
    value = getattr(module, name, None)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise UsageError(f"--constant {spec!r}: {module_name} has no number named {name}")
    tree = ast.parse(Path(module.__file__).read_text(encoding="utf-8"))
    assigned = {target.id for node in tree.body if isinstance(node, (ast.Assign, ast.AnnAssign))
                for target in (node.targets if isinstance(node, ast.Assign) else [node.target])
                if isinstance(target, ast.Name)}
    if name not in assigned:
        raise UsageError(f"--constant {spec!r}: {module_name} imports {name}; name the module that defines it")
    return module, name


def as_values(module, name, values) -> list:
    """``values`` as the constant's own type: an integer constant takes whole numbers only."""
    if isinstance(getattr(module, name), int):
        if not all(float(value).is_integer() for value in values):
            raise UsageError(f"--values: {name} is a whole number; give whole numbers")
        return [int(value) for value in values]
    return [float(value) for value in values]


def parse_numbers(text: str, option: str) -> list[float]:
    try:
        values = [float(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise UsageError(f"{option} {text!r}: give numbers separated by commas") from None
    if not values or not all(np.isfinite(values)):
        raise UsageError(f"{option} {text!r}: give finite numbers separated by commas")
    if len(set(values)) != len(values):
        raise UsageError(f"{option} {text!r}: each value once")
    return values


def compare(flip_by_run: dict, baseline, *, resamples: int = 2000, seed: int = 0, block: int | None = None) -> dict:
    """{run key: (frames, mean LDR-FLIP, relative difference to ``baseline``'s run, low, high,
    verdict)} over the frames every run has; ``flip_by_run`` {run key: {frame: LDR-FLIP}}."""
    from phrt.phrt_addon.report.captured import ratio_interval
    frames = sorted(set.intersection(*(set(flips) for flips in flip_by_run.values())))
    base = np.array([flip_by_run[baseline][frame] for frame in frames], np.float64)
    out = {}
    for key, flips in flip_by_run.items():
        run = np.array([flips[frame] for frame in frames], np.float64)
        total = float(base.sum())
        if len(frames) < 2 or total <= 0.0:
            out[key] = (len(frames), float(run.mean()) if len(frames) else float("nan"), None, None, None,
                        "no difference")
            continue
        difference = float(np.sum(run - base)) / total
        low, high = ratio_interval(run - base, base, resamples=resamples, seed=seed, block=block)
        verdict = "no difference" if low is None or high is None or low <= 0.0 <= high else \
            ("lower" if difference < 0 else "higher")
        out[key] = (len(frames), float(run.mean()), difference, low, high, verdict)
    return out


def reusable(run_dir: Path, mode: str, label: str, path: str, frame_range, resolution) -> bool:
    """Whether ``run_dir`` holds a complete ``mode`` run of this scene's path, frames and resolution,
    with its frames written, made on this CPU."""
    from phrt.phrt_addon.runs import run_files, summary as run_summary
    try:
        summary = run_files.read_summary(run_dir)
    except (FileNotFoundError, ValueError):
        return False
    wanted = {"mode": mode, "scene": label, "path": path, "frame_range": list(frame_range),
              "resolution": list(resolution), "images": "exr"}
    return not summary.get("partial", False) and all(summary.get(key) == value for key, value in wanted.items()) \
        and (summary.get("machine") or {}).get("cpu_model") == run_summary.machine_info()["cpu_model"]




def run_path(args, module, name, values, fractions, out: Path) -> list[dict]:
    """Render the runs (see the module docstring); one row per (budget at, value)."""
    from phrt.cli import blender_process
    from phrt.cli.lockstep import close_run, step_in_lockstep
    from phrt.engine import session
    from phrt.engine.runs import camera_path, replay
    from phrt.phrt_addon.report import metrics
    from phrt.phrt_addon.runs import run_files
    bpy = blender_process.blender()
    label = blender_process.load_scene(args.scene)
    scene = bpy.context.scene
    width, height = args.resolution
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
    camera = camera_path.find_path(scene, args.path)
    frame_range = camera_path.parse_frames(args.frames, camera_path.path_frame_range(scene, camera))
    out.mkdir(parents=True, exist_ok=True)
    keys = [(fraction, value) for fraction in fractions for value in values]
    folders = {key: out / f"at{key[0]!r}-{name}-{key[1]!r}" for key in keys}
    default = getattr(module, name)
    engine_session = session.current()
    with blender_process.quiet_stdout():
        for mode in ("RASTER", "RAYTRACE"):
            if not reusable(out / mode.lower(), mode, label, camera.name, frame_range, args.resolution):
                shutil.rmtree(out / mode.lower(), ignore_errors=True)
                replay.replay(scene, camera, frame_range, mode, out / mode.lower(), images="exr", scene_label=label)
        runs, value_of, failed = [], {}, {}

        def before(run):
            engine_session.replay = run.state  # the frame renderer this render uses
            setattr(module, name, value_of[id(run)])

        try:
            for key in keys:
                shutil.rmtree(folders[key], ignore_errors=True)
                runs.append(replay.ReplayRun(scene, camera, frame_range, "HYBRID", folders[key], images="exr",
                                             scene_label=label, budget_at=key[0], budget_search_dirs=[out],
                                             overrides={"selection": args.selection.upper()}, restores_scene=False))
                value_of[id(runs[-1])] = key[1]
            failed = step_in_lockstep(runs, before_step=before)
            for position in reversed(range(len(runs))):  # the first run's state restored last
                if position in failed:
                    close_run(runs[position])
                else:
                    runs[position].finish()
        except BaseException:
            for run in reversed(runs):
                close_run(run)
            raise
        finally:
            setattr(module, name, default)
            engine_session.replay = None
            if runs:
                runs[0].restore_scene()
    if failed:
        first = next(iter(failed.values()))
        raise RunFailed(f"{len(failed)} run(s) failed: {type(first).__name__}: {first}")
    reference = run_files.run_images(out / "raytrace")
    rows = []
    for fraction in fractions:
        flips = {}
        for value in values:
            images = run_files.run_images(folders[(fraction, value)])
            flips[value] = {frame: metrics.flip(metrics.read_image(reference[frame]), metrics.read_image(path))
                            for frame, path in images.items() if frame in reference and frame > frame_range[0]}
        compared = compare(flips, values[0], block=args.block)
        for value in values:
            summary = run_files.read_summary(folders[(fraction, value)])
            frames, mean_flip, difference, low, high, verdict = compared[value]
            rows.append(dict(budget_at=fraction, budget_ms=summary["budget_ms"], value=value, frames=frames,
                             mean_flip=mean_flip, difference=difference, low=low, high=high, verdict=verdict,
                             p95_over_budget=summary["p95_over_budget"],
                             selected_per_frame=summary["mean_n_selected"],
                             flips_per_100=summary["selection_flips_per_element_per_100_frames"]["mean"]))
    return rows


def table(rows, name) -> str:
    def percent(value):
        return "" if value is None else f"{100.0 * value:+.1f}%"
    lines = [f"| budget at | ms | {name} | frames | LDR-FLIP | vs first [90%] | verdict | p95 / budget | traced "
             "| flips / 100 |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        interval = "" if row["low"] is None else f" [{percent(row['low'])}, {percent(row['high'])}]"
        lines.append(f"| {row['budget_at']:g} | {row['budget_ms']:.1f} | {row['value']:g} | {row['frames']} | "
                     f"{row['mean_flip']:.5f} | {percent(row['difference'])}{interval} | {row['verdict']} | "
                     f"{row['p95_over_budget']:.2f} | {row['selected_per_frame']:.2f} | {row['flips_per_100']:.2f} |")
    return "\n".join(lines)


def parse_args(argv):
    parser = argparse.ArgumentParser(description="A selection constant A/B'd in lockstep on one camera path")
    parser.add_argument("scene", help="a sample scene's name or a .blend file")
    parser.add_argument("--path", required=True, help="the camera path (the camera's name)")
    parser.add_argument("--frames", default="1-120")
    parser.add_argument("--constant", required=True, help="module.NAME in phrt_addon/select")
    parser.add_argument("--values", required=True, help="values, the first the baseline")
    parser.add_argument("--budget-at", default="0.25,0.5")
    parser.add_argument("--resolution", default="320x240")
    parser.add_argument("--selection", default="benefit", choices=("benefit", "paper"))
    parser.add_argument("--out", default=None, help="default out/constant-ab/<scene>-<path>")
    parser.add_argument("--block", type=int, default=None,
                        help="the bootstrap's block of frames (default: the yardstick's, n ** (1/3))")

    def error(message):
        raise UsageError(message)
    parser.error = error
    args = parser.parse_args(argv)
    if args.block is not None and args.block < 1:
        raise UsageError(f"--block {args.block}: at least 1 frame")
    try:
        width, height = (int(part) for part in args.resolution.lower().split("x"))
    except ValueError:
        raise UsageError(f"--resolution {args.resolution!r}: give it as WIDTHxHEIGHT, e.g. 320x240") from None
    if width <= 0 or height <= 0:
        raise UsageError(f"--resolution {args.resolution!r}: both sides must be positive")
    args.resolution = (width, height)
    return args


def main(argv=None) -> int:
    try:
        args = parse_args(argv)
        module, name = parse_constant(args.constant)
        values = as_values(module, name, parse_numbers(args.values, "--values"))
        fractions = parse_numbers(args.budget_at, "--budget-at")
        if len(set(values)) < 2:
            raise UsageError(f"--values {args.values!r}: give at least two different values")
        if not all(0.0 <= fraction <= 1.0 for fraction in fractions):
            raise UsageError(f"--budget-at {args.budget_at!r}: fractions of the way, within 0..1")
    except UsageError as error:
        print(f"constant-ab: {error}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path("out") / "constant-ab" / f"{Path(args.scene).stem}-{args.path}"
    try:
        rows = run_path(args, module, name, values, fractions, out)
    except RunFailed as error:  # the renders' failure, not the user's: exit 1
        print(f"constant-ab: {error}", file=sys.stderr)
        return 1
    except Exception as error:  # a scene or path that is not there: one line, exit 2
        print(f"constant-ab: {str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__}",
              file=sys.stderr)
        return 2
    with open(out / "constant_ab.csv", "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    print(table(rows, name))
    print(f"wrote {out / 'constant_ab.csv'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
