"""``make paper``: the paper's experiment on both sample scenes (long: many hours here).

Section VI of the paper renders three camera paths of each of its two
environments in raster, hybrid and ray traced modes, 1000 frames each, and
reports the mean frame times (its Table II).  This does the same for ``arcade``
(our Sponza) and ``atrium`` - 2 scenes x 3 paths x 3 modes x 1000 frames at the
scenes' 640x480, the hybrid runs at the scenes' own budget (40% of the way
from raster to ray traced time, resolved from the two runs beside it) - plus a
sweep of ``path1`` of each scene (``phrt sweep``: 5 budgets x every selection
variant, and the oracle), then writes one report of everything to
``out/paper/report/``: Table II beside the paper's ratios, the error-time
curves, regret and popping.

Every run is a job that is skipped when complete, so an interrupted ``make
paper`` continues where it stopped.  On 2 CPU cores without a GPU a frame
takes about a second: about 18,000 frames for Table II and 64,000 for the two
sweeps.  ``--frames``, ``--budgets`` and ``--resolution`` make a shorter one.

    python -m phrt.paper [--out out/paper] [--frames A-B] [--budgets N] [--resolution WxH]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

SCENES = ("arcade", "atrium")
PATHS = ("path1", "path2", "path3")
SWEPT_PATH = "path1"


def main(argv=None):
    parser = argparse.ArgumentParser(description="PHRT: the paper's Table II and error-time curves")
    parser.add_argument("--out", default="out/paper")
    parser.add_argument("--frames", default=None, help="frame range A-B of every path (default: all 1000)")
    parser.add_argument("--budgets", default=5, type=int, help="budgets of each sweep (default 5)")
    parser.add_argument("--resolution", default=None, help="WxH (default: the scenes' 640x480)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    out = Path(args.out)
    from . import cli
    from .engine import replay
    from .phrt_addon import oracle, plan, report

    common = (["--frames", args.frames] if args.frames else []) + \
             (["--resolution", args.resolution] if args.resolution else [])
    run_dirs, oracle_dirs = [], []
    for scene_name in SCENES:
        # path1: the sweep (its raster, raytrace and hybrid runs are Table II's too).
        sweep_dir = out / f"{scene_name}-{SWEPT_PATH}-sweep"
        status = cli.main(["sweep", scene_name, "--path", SWEPT_PATH, "--budgets", str(args.budgets),
                           "--out", str(sweep_dir), *common])
        if status != 0:
            return status
        swept = plan.read_plan(sweep_dir / plan.PLAN_JSON)
        run_dirs += [sweep_dir / job.id for job in swept.runs]
        oracle_dirs.append(sweep_dir / oracle.ORACLE_DIR)
        for path in PATHS:
            if path == SWEPT_PATH:
                continue
            # Raster and raytrace first: the hybrid run's budget (the scene's Budget At) resolves from them.
            for mode in ("raster", "raytrace", "hybrid"):
                run_dir = replay.default_run_dir(out / "runs", scene_name, path, mode)
                if plan.run_is_complete(run_dir, _expected(run_dir, args, swept)):
                    print(f"phrt: {run_dir}: complete, skipped")
                else:
                    status = cli.main(["render", scene_name, "--path", path, "--mode", mode, "--out", str(run_dir),
                                       *common])
                    if status != 0:
                        return status
                run_dirs.append(run_dir)
    files = report.build_report(run_dirs, out_dir=out / "report", oracle_dir=oracle_dirs)
    print(f"paper: report {files.markdown} ({len(run_dirs)} runs) in {time.perf_counter() - started:.0f} s")
    return 0


def _expected(run_dir, args, swept):
    """A plan-like record of what a complete run of another path looks like (frames, resolution)."""
    from .phrt_addon import plan
    from .sample_scenes.camera_paths import FRAMES
    if args.frames:
        start, end = (int(part) for part in args.frames.split("-"))
    else:
        start, end = 1, FRAMES  # the sample scenes' paths are keyed on every frame of 1..FRAMES
    return plan.Plan(scene="", scene_label="", path="", frames=[start, end], resolution=list(swept.resolution),
                     budgets=[], oracle_every=swept.oracle_every, jobs=[])


if __name__ == "__main__":
    sys.exit(main())
