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

Every run is a job of a plan (``phrt_addon/runs/plan.py``): each sweep's own, and
one plan of the other paths' runs of both scenes in ``out/paper/runs/``.  A
complete job is skipped, so an interrupted ``make paper`` continues where it
stopped.  On 2 CPU cores without a GPU a frame takes about a second: about
18,000 frames for Table II and 64,000 for the two sweeps.  ``--frames``,
``--budgets`` and ``--resolution`` make a shorter one; ``--workers N`` runs
every plan on a Dask LocalCluster of N worker processes and ``--scheduler
ADDRESS`` on an existing Dask cluster (``make paper WORKERS=N`` /
``SCHEDULER=ADDRESS``, docs/cluster.md).

    python -m phrt.cli.paper [--out out/paper] [--frames A-B] [--budgets N] [--resolution WxH]
                         [--workers N | --scheduler ADDRESS]
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
    parser.add_argument("--workers", default=None, type=int, metavar="N",
                        help="run the plans on a Dask LocalCluster of N worker processes")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="run the plans on the Dask cluster whose scheduler is at ADDRESS (docs/cluster.md)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    out = Path(args.out)
    from . import blender_process
    from . import sweep as sweep_engine
    from ..phrt_addon.runs import executors

    blender_process.import_blender()
    try:
        executor = sweep_engine.make_executor(args.workers, args.scheduler)
        if isinstance(executor, executors.DaskExecutor):
            executor.start()
            print(f"paper: running on the Dask cluster at {executor.address}; dashboard {executor.dashboard_link}",
                  flush=True)
    except executors.ExecutorError as error:
        print(f"paper: error: {error}", file=sys.stderr)
        return 2
    try:
        on_cluster = ["--scheduler", executor.address] if isinstance(executor, executors.DaskExecutor) else []
        return _run(args, out, started, executor, on_cluster)
    finally:
        if isinstance(executor, executors.DaskExecutor):
            executor.close()


def _run(args, out, started, executor, on_cluster):
    from .. import cli
    from . import sweep as sweep_engine
    from ..phrt_addon.report import oracle
    from ..phrt_addon.runs import plan
    from ..phrt_addon import report

    common = (["--frames", args.frames] if args.frames else []) + \
             (["--resolution", args.resolution] if args.resolution else [])
    run_dirs, oracle_dirs = [], []
    for scene_name in SCENES:
        # path1: the sweep (its raster, raytrace and hybrid runs are Table II's too).
        sweep_dir = out / f"{scene_name}-{SWEPT_PATH}-sweep"
        status = cli.main(["sweep", scene_name, "--path", SWEPT_PATH, "--budgets", str(args.budgets),
                           "--out", str(sweep_dir), *common, *on_cluster])
        if status != 0:
            return status
        swept = plan.read_plan(sweep_dir / plan.PLAN_JSON)
        run_dirs += [sweep_dir / job.id for job in swept.runs]
        oracle_dirs.append(sweep_dir / oracle.ORACLE_DIR)
    # The other paths of both scenes: one plan, each hybrid run after the raster and raytrace runs
    # its budget (the scene's Budget At) resolves from.
    others = other_paths_plan(swept.frames, swept.resolution)
    plan_path = plan.write_plan(others, out / "runs")
    total = len(others.jobs)
    counter = [0]

    def show(outcome):
        counter[0] += 1
        line = f"paper: [{counter[0]}/{total}] {outcome.job_id}: {outcome.status}"
        if outcome.status == "done":
            line += f" in {outcome.seconds:.1f} s ({outcome.message})"
        elif outcome.status == "failed":
            line += f": {outcome.message}"
        print(line, flush=True)

    outcomes = executor.run(plan_path, others, sweep_engine.execute_job, on_outcome=show)
    failed = [outcome.job_id for outcome in outcomes if outcome.status == "failed"]
    if failed:
        print(f"paper: {len(failed)} runs failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    run_dirs += [out / "runs" / job.id for job in others.runs]
    files = report.build_report(run_dirs, out_dir=out / "report", oracle_dir=oracle_dirs)
    print(f"paper: report {files.markdown} ({len(run_dirs)} runs) in {time.perf_counter() - started:.0f} s")
    return 0


def other_paths_plan(frames, resolution):
    """Raster, raytrace and hybrid (at the scene's own budget) runs of every path of both scenes
    but the swept one, named ``<scene>-<path>-<mode>`` as ``phrt render`` names them."""
    from ..phrt_addon.runs import plan
    jobs = []
    for scene_name in SCENES:
        for path in PATHS:
            if path == SWEPT_PATH:
                continue
            ids = {mode: plan.run_id(scene_name, path, mode) for mode in ("RASTER", "RAYTRACE", "HYBRID")}
            jobs.append(plan.Job(ids["RASTER"], "run", "RASTER", scene=scene_name, path=path))
            jobs.append(plan.Job(ids["RAYTRACE"], "run", "RAYTRACE", scene=scene_name, path=path))
            # The paper's heuristic, whatever the sample scene's own selection (generate.SELECTION).
            jobs.append(plan.Job(ids["HYBRID"], "run", "HYBRID", scene=scene_name, path=path,
                                 depends_on=[ids["RASTER"], ids["RAYTRACE"]], overrides=dict(plan.BASELINE)))
    return plan.Plan(scene=SCENES[0], scene_label=SCENES[0], path=PATHS[0], frames=list(frames),
                     resolution=list(resolution), budgets=[], oracle_every=0, jobs=jobs)


if __name__ == "__main__":
    sys.exit(main())
