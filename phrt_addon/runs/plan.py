"""A sweep as a plan of independent jobs (``DIR/plan.json``) and the executors that run it.

``phrt sweep`` renders one camera path in RASTER and RAYTRACE, then in HYBRID
at N budgets between their mean frame times (``budget_at`` = 1/(N+1) ...
N/(N+1) of the way, resolved from the two runs), each budget in every
*variant* of the selection (:data:`VARIANTS`: both cost models, the selection
weight I at 0 / 0.1 / 0.5, the paper's greedy order and R per predicted ms,
the paper's relevance and the error-aware one), then the oracle on sampled
frames of all hybrid runs, then a report.

Each job writes exactly one directory under the sweep folder, first under a
temporary name (``.<id>.partial-<host>-<pid>``) that is renamed when the job is
complete, so an interrupted job never looks complete; a later attempt removes
only the temporary folders of attempts whose process is gone (same host, no
such process: ``runs/lock.tag_is_dead``), never a live one's.  A run is
*complete* when its directory holds a final ``summary.json`` whose recorded
work (``runs/work.py``: scene file and its content hash, frames, resolution,
settings, PHRT's version) is the plan's; the oracle when its ``oracle.json``
was computed from the current runs.  Complete jobs are skipped when the plan
is run again; any other is redone, its outcome saying why in one line.

Job ids are folder names under the sweep folder: :func:`check_job_id` admits
only a plain name (no separator, not ``.`` or ``..``, no leading dot), when a
plan is built and when it is read back, so no job ever writes or removes
anything outside the sweep folder; two jobs of one id (budgets closer than the
id's two decimals) are refused before ``plan.json`` is written.

Executors (:class:`Executor`) take the plan and a job function
``execute(plan_path, job_id) -> JobOutcome`` (``cli/sweep.py:execute_job``:
module level, picklable, one Blender per process) and run every job after the
jobs it ``depends_on``.  :class:`LocalExecutor` runs them one after the other
in this process; ``phrt_addon/runs/executors.py`` has the Dask one (one task per
job on worker processes of their own, docs/cluster.md).  The jobs read
everything they need from ``plan.json`` and the directories of the jobs they
depend on.  Budgets in milliseconds are resolved from the raster and raytrace
runs on the machine that runs the hybrid job: all jobs of a plan should run on
machines of one kind.

A job may name its own scene and camera path (``make paper`` puts the runs of
several paths of both scenes in one plan); by default it replays the plan's.  Plain Python, no ``bpy``.
"""
from __future__ import annotations

import json
import os
import shutil
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Protocol, Sequence

from .. import defaults
from ..report import oracle
from .. import schema
from . import atomic, lock, work

PLAN_JSON = "plan.json"
PLAN_VERSION = 1
REPORT_DIR = "report"
# A lockstep sweep's second raster run, in the hybrid runs' group: the oracle's shared time on the
# machine they met (the first raster run, rendered before them, still resolves the budgets).
GROUP_RASTER = "group"
DEFAULT_BUDGETS = 5

# The baseline is the paper's heuristic with the engine's measured cost model; each other
# variant changes one knob.  Keys are the Scene.phrt settings a replay overrides.
BASELINE = {"cost_mode": "MEASURED", "selection_weight": defaults.SELECTION_WEIGHT,
            "selection_order": "RELEVANCE", "relevance": "PAPER", "selection": "PAPER", "quality_tiers": False}
VARIANTS = {
    "measured": {},
    "papercost": {"cost_mode": "PAPER"},
    "i0": {"selection_weight": 0.0},
    "i0.1": {"selection_weight": 0.1},
    "rperms": {"selection_order": "RELEVANCE_PER_MS"},
    "error": {"relevance": "ERROR"},
    "benefit": {"selection": "BENEFIT"},
    "tiers": {"selection": "BENEFIT", "quality_tiers": True},
}


class PlanError(ValueError):
    """A plan that cannot be run (duplicate or unsafe job ids...): the message is one line."""


def check_job_id(job_id) -> str:
    """``job_id`` when it is a plain folder name, else PlanError."""
    text = job_id if isinstance(job_id, str) else None
    if (not text or text in (".", "..") or text.startswith(".") or len(text.encode("utf-8")) > 255
            or any(separator in text for separator in ("/", "\\", "\0", os.sep, os.altsep or "/"))
            or any(ord(character) < 32 for character in text)):
        raise PlanError(f"job id {job_id!r} is not a plain folder name (no separators, not '.' or '..', "
                        f"no leading dot)")
    return text


def budget_fractions(count: int) -> list[float]:
    """``count`` budgets spread evenly strictly between raster (0) and raytrace (1)."""
    if count < 1:
        raise ValueError(f"a sweep needs at least 1 budget, not {count}")
    return [round(index / (count + 1), 6) for index in range(1, count + 1)]


@dataclass
class Job:
    """One independent job: a run (``kind='run'``) or the oracle (``kind='oracle'``)."""

    id: str  # also the name of the directory it writes under the sweep folder
    kind: str
    mode: str | None = None
    budget_at: float | None = None
    variant: str | None = None
    overrides: dict = field(default_factory=dict)
    depends_on: list = field(default_factory=list)
    budget_ms: float | None = None  # a fixed frame budget (a hybrid run), instead of budget_at or the scene's
    scene: str | None = None  # None: the plan's scene (and scene_label), path and frames
    scene_label: str | None = None
    path: str | None = None


@dataclass
class Plan:
    """Everything the jobs of a sweep need, written to ``plan.json``."""

    scene: str  # a sample scene name or an absolute .blend path
    scene_label: str
    path: str
    frames: list
    resolution: list
    budgets: list
    oracle_every: int
    jobs: list
    version: int = PLAN_VERSION

    def job(self, job_id: str) -> Job:
        for job in self.jobs:
            if job.id == job_id:
                return job
        raise KeyError(f"no job '{job_id}' in the plan")

    def target(self, job: Job) -> tuple:
        """(scene, scene label, camera path) that ``job`` replays: its own, else the plan's."""
        if job.scene is None:
            return self.scene, self.scene_label, job.path or self.path
        label = job.scene_label or (Path(job.scene).stem if job.scene.lower().endswith(".blend") else job.scene)
        return job.scene, label, job.path or self.path

    def in_dependency_order(self) -> list:
        """The jobs, each after the jobs it depends on (plan order where it allows);
        ValueError for a dependency on an unknown job or a cycle."""
        ids = {job.id for job in self.jobs}
        if len(ids) != len(self.jobs):
            raise ValueError("the plan has two jobs of one id")
        for job in self.jobs:
            unknown = [dependency for dependency in job.depends_on if dependency not in ids]
            if unknown:
                raise ValueError(f"job '{job.id}' depends on unknown job(s) {', '.join(unknown)}")
        ordered, placed, pending = [], set(), list(self.jobs)
        while pending:
            ready = next((job for job in pending if all(dependency in placed for dependency in job.depends_on)),
                         None)
            if ready is None:
                raise ValueError(f"jobs {', '.join(job.id for job in pending)} depend on each other")
            ordered.append(ready)
            placed.add(ready.id)
            pending.remove(ready)
        return ordered

    @property
    def runs(self) -> list:
        return [job for job in self.jobs if job.kind == "run"]

    @property
    def reported_runs(self) -> list:  # the group raster run only times the oracle's shared part
        return [job for job in self.runs if not is_group_raster(job)]

    def to_json(self) -> dict:
        return {"version": self.version, "scene": self.scene, "scene_label": self.scene_label, "path": self.path,
                "frames": list(self.frames), "resolution": list(self.resolution), "budgets": list(self.budgets),
                "oracle_every": self.oracle_every, "jobs": [asdict(job) for job in self.jobs]}

    @classmethod
    def from_json(cls, data: dict) -> "Plan":
        if data.get("version") != PLAN_VERSION:
            raise ValueError(f"plan version {data.get('version')!r} is not {PLAN_VERSION}")
        jobs = [Job(**job) for job in data["jobs"]]
        for job in jobs:
            check_job_id(job.id)
            for dependency in job.depends_on:
                check_job_id(dependency)
        return cls(scene=data["scene"], scene_label=data["scene_label"], path=data["path"],
                   frames=list(data["frames"]), resolution=list(data["resolution"]),
                   budgets=list(data["budgets"]), oracle_every=int(data["oracle_every"]), jobs=jobs)


def is_group_raster(job: Job) -> bool:
    return job.kind == "run" and job.mode == "RASTER" and job.variant == GROUP_RASTER


def run_images(job: Job) -> str:
    """The images a run job writes: EXR frames, but none for the group raster run (only its times are read)."""
    return "none" if is_group_raster(job) else "exr"


def shared_raster(plan: "Plan", folder, oracle_job: Job):
    """The run folder the oracle takes its shared time from: the group raster run of its path when
    complete (lockstep), else the first raster run it depends on; None without either."""
    folder = Path(folder)
    for job in (job for job in plan.jobs if is_group_raster(job) and plan.target(job) == plan.target(oracle_job)):
        if run_is_complete(folder / job.id, plan):
            return folder / job.id
    first = next((dependency for dependency in oracle_job.depends_on if plan.job(dependency).mode == "RASTER"), None)
    return folder / first if first is not None else None


def in_lockstep_group(job: Job) -> bool:
    """A job a lockstep sweep renders frame by frame with the others of its path."""
    return job.kind == "run" and (job.mode == "HYBRID" or is_group_raster(job))


def run_id(scene_label: str, path: str, mode: str, budget_at: float | None = None, variant: str | None = None) -> str:
    base = f"{scene_label}-{path}-{mode.lower()}"
    return base if budget_at is None else f"{base}-at{budget_at:.2f}-{variant}"


def build_plan(scene: str, scene_label: str, path: str, frames, resolution, budgets: Sequence[float],
               variants: Sequence[str] = tuple(VARIANTS), oracle_every: int = oracle.DEFAULT_EVERY,
               selection: str | None = None, group_raster: bool = False) -> Plan:
    """The jobs of a sweep: raster, raytrace, every (budget, variant) hybrid, then the oracle.
    ``selection`` ('paper' or 'benefit'): the selection of every variant that does not set its
    own (``benefit`` does), instead of the paper's.  ``group_raster`` (a lockstep sweep): a second
    raster run, rendered with the hybrid runs, gives the oracle its shared time."""
    unknown = [name for name in variants if name not in VARIANTS]
    if unknown:
        raise ValueError(f"unknown variants {unknown}: use some of {', '.join(VARIANTS)}")
    if not budgets:
        raise ValueError("a sweep needs at least one budget")
    for fraction in budgets:
        if not 0.0 <= float(fraction) <= 1.0:
            raise ValueError(f"budget fraction {fraction} is outside 0..1")
    base = dict(BASELINE)
    if selection is not None:
        if str(selection).lower() not in schema.SELECTIONS:
            raise ValueError(f"selection must be one of {', '.join(schema.SELECTIONS)}, not {selection!r}")
        base["selection"] = str(selection).upper()
    raster = Job(run_id(scene_label, path, "RASTER"), "run", "RASTER")
    raytrace = Job(run_id(scene_label, path, "RAYTRACE"), "run", "RAYTRACE")
    jobs = [raster, raytrace]
    for fraction in budgets:
        for name in variants:
            jobs.append(Job(run_id(scene_label, path, "HYBRID", float(fraction), name), "run", "HYBRID",
                            budget_at=float(fraction), variant=name, overrides={**base, **VARIANTS[name]},
                            depends_on=[raster.id, raytrace.id]))
    hybrids = [job.id for job in jobs if job.mode == "HYBRID"]
    jobs.append(Job(oracle.ORACLE_DIR, "oracle", depends_on=[raster.id, raytrace.id, *hybrids]))
    if group_raster and hybrids:  # rendered in the hybrid runs' group, before the oracle: not its dependency
        jobs.insert(len(jobs) - 1, Job(f"{raster.id}-{GROUP_RASTER}", "run", "RASTER", variant=GROUP_RASTER,
                                       depends_on=[raster.id, raytrace.id]))
    seen = {}
    for job in jobs:
        check_job_id(job.id)
        if job.id in seen:
            raise PlanError(f"budgets {seen[job.id]:g} and {job.budget_at:g} give the same run id '{job.id}': give "
                            f"budgets at least 0.01 apart (--budget-at), or fewer --budgets (at most 98)")
        seen[job.id] = job.budget_at
    return Plan(scene=scene, scene_label=scene_label, path=path, frames=[int(frames[0]), int(frames[1])],
                resolution=[int(resolution[0]), int(resolution[1])], budgets=[float(b) for b in budgets],
                oracle_every=int(oracle_every), jobs=jobs)


def write_plan(plan: Plan, folder) -> Path:
    """Write ``folder/plan.json`` (through a temporary file); returns its path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return atomic.write_text(folder / PLAN_JSON, json.dumps(plan.to_json(), indent=2) + "\n")


def read_plan(plan_path) -> Plan:
    return Plan.from_json(json.loads(Path(plan_path).read_text(encoding="utf-8")))


def wanted_work(plan: Plan, job: Job, scene_file) -> dict:
    """The work a run of ``job`` records when done from ``scene_file`` (the .blend it opens)."""
    return work.work_record(scene_file, plan.frames, plan.resolution, mode=job.mode, images=run_images(job),
                            budget_ms=job.budget_ms, budget_at=job.budget_at, overrides=job.overrides)


def run_redo_reason(run_dir, plan: Plan, wanted: dict | None = None) -> str | None:
    """Why the run in ``run_dir`` must be (re)done for ``plan``, None when it is complete: a final
    summary of the plan's whole frame range and resolution, and (given ``wanted``) the same work."""
    path = Path(run_dir) / schema.SUMMARY_JSON
    if not path.is_file():
        return "no run yet" if not Path(run_dir).exists() else "the run did not finish"
    try:
        summary = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return "its summary.json cannot be read"
    if summary.get("partial") or summary.get("cancelled"):
        return "the run did not finish"
    if wanted is not None:
        difference = work.work_difference(summary.get("work"), wanted)
        if difference is not None:
            return difference
    expected = plan.frames[1] - plan.frames[0] + 1
    if summary.get("frame_count") != expected:
        return f"{summary.get('frame_count')} frames, not {expected}"
    if list(summary.get("resolution") or []) != plan.resolution:
        return f"resolution {summary.get('resolution')}, not {plan.resolution}"
    return None


def run_is_complete(run_dir, plan: Plan, wanted: dict | None = None) -> bool:
    """A finished run of the plan's whole frame range (not partial, not cancelled; the same work)."""
    return run_redo_reason(run_dir, plan, wanted) is None


def job_is_complete(plan: Plan, folder, job: Job, wanted: dict | None = None) -> bool:
    folder = Path(folder)
    if job.kind == "run":
        return run_is_complete(folder / check_job_id(job.id), plan, wanted)
    results = oracle.read_results(folder / check_job_id(job.id))
    if results is None:
        return False
    runs = [dependency for dependency in job.depends_on if plan.job(dependency).mode == "HYBRID"]
    raster = shared_raster(plan, folder, job)
    if raster is not None and not results.is_shared_from(raster):  # redone, or another raster run now
        return False
    return all(results.is_current_for(run, folder / run) for run in runs)


def partial_dir(folder, job: Job) -> Path:
    """Where a job writes before it is complete (this host and process in the name)."""
    return Path(folder) / f".{check_job_id(job.id)}.partial-{lock.owner_tag()}"


def dead_attempts(folder, job: Job) -> list:
    """Temporary folders of earlier attempts at ``job`` whose process is gone (this host, no such
    process) or is this one: the ones a new attempt may remove."""
    found = []
    prefix = f".{check_job_id(job.id)}.partial-"
    for path in Path(folder).glob(f"{prefix}*"):
        tag = path.name[len(prefix):]
        if tag == lock.owner_tag() or lock.tag_is_dead(tag):
            found.append(path)
    return found


def inside(folder, path) -> Path:
    """``path`` when it lies strictly inside ``folder`` (after resolving links), else PlanError."""
    folder, resolved = Path(folder).resolve(), Path(path).resolve()
    if resolved == folder or folder not in resolved.parents:
        raise PlanError(f"'{path}' is not inside the sweep folder '{folder}': not removed")
    return Path(path)


def publish(partial: Path, final: Path) -> None:
    """Rename a finished job's directory to its final name (replacing an incomplete one)."""
    if final.exists():
        shutil.rmtree(inside(final.parent, final))
    os.replace(partial, final)


@dataclass
class JobOutcome:
    job_id: str
    status: str  # 'done', 'skipped' or 'failed'
    seconds: float = 0.0
    message: str = ""  # one line
    worker: str = ""  # 'host:pid' of the process that ran it, when not this one


class Executor(Protocol):
    """Runs every job of a plan after its dependencies; returns one outcome per job."""

    def run(self, plan_path: Path, plan: Plan, execute: Callable[[str, str], JobOutcome],
            on_outcome: Callable[[JobOutcome], None] | None = None) -> list: ...


class LocalExecutor:
    """The jobs one after the other, in plan order (dependencies come first), in this process.
    A job whose dependency failed is not run (status 'failed', saying which)."""

    def run(self, plan_path, plan, execute, on_outcome=None):
        outcomes, failed = [], set()
        for job in plan.in_dependency_order():
            missing = [dependency for dependency in job.depends_on if dependency in failed]
            if missing:
                outcome = JobOutcome(job.id, "failed", message=f"not run: {', '.join(missing)} failed")
            else:
                begin = time.perf_counter()
                try:
                    outcome = execute(str(plan_path), job.id)
                except Exception as error:  # one failed job must not hide what the others did
                    outcome = JobOutcome(job.id, "failed", time.perf_counter() - begin,
                                         f"{type(error).__name__}: {error}")
            if outcome.status == "failed":
                failed.add(job.id)
            outcomes.append(outcome)
            if on_outcome is not None:
                on_outcome(outcome)
        return outcomes
