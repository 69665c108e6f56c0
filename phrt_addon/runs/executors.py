"""Running a plan's jobs on a Dask cluster (the progress line of a plan's run: ``runs/progress.py``).

:class:`DaskExecutor` has the interface of ``plan.LocalExecutor``
(``run(plan_path, plan, execute, on_outcome)``): each job of the plan is one Dask task,
``run_job(execute, plan_path, job_id, *outcomes of its depends_on)``, submitted with the
resource annotation ``phrt=1`` and ``retries=2``.  Workers are processes with the resource
``phrt=1`` (a LocalCluster of ``--workers N`` here, or ``dask worker ... --resources phrt=1`` on
render nodes), so a worker times one replay at a time.  A task that raises is retried, on any
worker; a task whose worker dies is run again by the scheduler; a job's directory is only ever
published complete (``plan.publish``) and a retry clears what a dead attempt left, so a
half-written run is never taken for a result.  A job whose input is bad (a missing file or
camera path) returns a failed outcome at once instead of raising: retrying cannot help it.

Workers open the plan's files themselves: ``plan.json``, the sweep folder and every ``.blend`` it
names must be on storage all workers see at the same path (a sample scene name resolves on the
worker).  Before a plan runs, every worker is checked to see ``plan.json``.

Blender as a Python module has a main thread: the thread that imported ``bpy``.  Files must be
opened there (opening one from another thread leaves Blender to crash when the process ends);
rendering may happen in any thread.  A Dask worker runs tasks in a thread of its own and its
event loop in the process's main thread, so a worker plugin given to :class:`DaskExecutor`
(``cli/dask_worker.py``) imports ``bpy`` and registers PHRT on the event loop when the worker
starts, and :func:`on_main_thread` runs the file loading of a job there.

Dask is optional: nothing here imports it until a :class:`DaskExecutor` starts.  No ``bpy``.
"""
from __future__ import annotations

import concurrent.futures
import logging
import os
import re
import socket
import threading
import time
import uuid
import warnings
from dataclasses import replace
from pathlib import Path

from .plan import JobOutcome

RESOURCE = "phrt"  # each worker has phrt=1; each job asks for phrt=1: one replay at a time per worker
RETRIES = 2
CONNECT_TIMEOUT_S = 10
DEFAULT_DASHBOARD = "127.0.0.1:8787"  # this machine only: the dashboard shows task names, paths and logs
LOCAL_HOST = "127.0.0.1"  # a LocalCluster's scheduler and workers listen here only
CLOSE_TIMEOUT_S = 10.0  # how long closing waits for a LocalCluster's workers to leave first
PIP_DASK = "dask[distributed,diagnostics]==2026.8.0"
_ADDRESS = re.compile(r"^(?:(?:tcp|tls|ws|wss|ucx)://)?(?:\[[0-9a-fA-F:]+\]|[A-Za-z0-9_.-]+):\d{1,5}$")


class ExecutorError(ValueError):
    """The cluster cannot run the plan (Dask missing, scheduler unreachable, no suitable worker):
    the message says what is wrong and how to fix it."""


def check_scheduler_address(address: str) -> str:
    """``address`` when it looks like ``tcp://HOST:PORT`` (or ``HOST:PORT``), else ExecutorError."""
    if not _ADDRESS.match(address or ""):
        raise ExecutorError(f"malformed scheduler address '{address}': give tcp://HOST:PORT, e.g. "
                            f"--scheduler tcp://render1:8786")
    return address


def executor_options(workers=None, scheduler=None, dashboard=None, tls_ca_file=None, tls_cert=None,
                     tls_key=None) -> dict:
    """The keyword options of :func:`make_executor` for the ``phrt sweep`` flags, checked
    (ExecutorError): --workers and --scheduler not both, a well-formed address, --dashboard only
    with --workers, the TLS files only (and all three) with a tls:// scheduler."""
    make_executor(workers, scheduler)
    check_tls_options(scheduler, tls_ca_file, tls_cert, tls_key)
    if dashboard is not None and workers is None:
        raise ExecutorError("--dashboard is for the LocalCluster of --workers: an existing cluster's dashboard is "
                            "its scheduler's")
    options = {} if dashboard is None else {"dashboard_address": dashboard}
    if tls_ca_file is not None:
        options["security"] = tls_security(tls_ca_file, tls_cert, tls_key)
    return options


def check_tls_options(scheduler, ca_file, cert, key):
    """ExecutorError unless the TLS files go with a tls:// scheduler: all three or none, each a
    readable file, and a tls:// scheduler is given them (Dask's own configuration
    ``distributed.comm.tls.*`` counts too)."""
    given = [value for value in (ca_file, cert, key) if value is not None]
    tls = bool(scheduler) and str(scheduler).startswith("tls://")
    if given and not tls:
        raise ExecutorError("--tls-ca-file/--tls-cert/--tls-key are for a tls:// --scheduler")
    if given and len(given) != 3:
        raise ExecutorError("give all of --tls-ca-file, --tls-cert and --tls-key for a tls:// scheduler")
    for value in given:
        if not os.path.isfile(value):
            raise ExecutorError(f"no TLS file '{value}'")
    if tls and not given and not _tls_configured():
        raise ExecutorError(f"the scheduler {scheduler} speaks TLS: give --tls-ca-file, --tls-cert and --tls-key "
                            f"(or Dask's distributed.comm.tls configuration; docs/cluster.md)")


def _tls_configured() -> bool:
    try:
        import dask.config
    except ImportError:
        return False
    return bool(dask.config.get("distributed.comm.tls.ca-file", None))


def tls_security(ca_file, cert, key):
    """A ``distributed.security.Security`` for a client of a TLS cluster (encryption required)."""
    import_distributed()
    from distributed.security import Security
    return Security(tls_ca_file=str(ca_file), tls_client_cert=str(cert), tls_client_key=str(key),
                    require_encryption=True)


def _probe(address: str, timeout_s: float):
    """OSError at once when nothing listens at a tcp address (Dask itself retries until its timeout)."""
    scheme, _, rest = address.rpartition("://")
    if scheme not in ("", "tcp"):
        return
    host, _, port = rest.rpartition(":")
    with socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s):
        pass


def import_distributed():
    try:
        import distributed
    except ImportError:
        raise ExecutorError(f"running on a Dask cluster needs Dask: pip install '{PIP_DASK}' "
                            f"(docs/cluster.md)") from None
    return distributed


def run_job(execute, plan_path: str, job_id: str, *dependencies: JobOutcome) -> JobOutcome:
    """The Dask task of one job: ``execute(plan_path, job_id)`` unless a job it depends on failed.
    Exceptions propagate (Dask retries the task)."""
    failed = [outcome.job_id for outcome in dependencies if outcome.status == "failed"]
    if failed:
        return JobOutcome(job_id, "failed", message=f"not run: {', '.join(failed)} failed")
    outcome = execute(plan_path, job_id)
    return replace(outcome, message=_one_line(outcome.message), worker=f"{socket.gethostname()}:{os.getpid()}")


def on_main_thread(function, *args):
    """``function(*args)`` on this process's main thread: directly when called there, else (a job
    in a Dask worker's task thread) on the worker's event loop, which runs in the main thread;
    blocks until it returns and returns its result or raises its exception."""
    if threading.current_thread() is threading.main_thread():
        return function(*args)
    try:
        from distributed import get_worker
        worker = get_worker()
    except (ImportError, ValueError):
        raise RuntimeError("Blender files can only be opened on the main thread (the thread that imported "
                           "bpy): run jobs on the main thread or in a Dask worker process") from None
    result = concurrent.futures.Future()

    def call():
        if threading.current_thread() is not threading.main_thread():
            result.set_exception(RuntimeError("this Dask worker's event loop is not on its process's main thread:"
                                              " start workers as processes (dask worker, LocalCluster)"))
            return
        try:
            result.set_result(function(*args))
        except BaseException as error:  # handed to the waiting task thread
            result.set_exception(error)

    worker.loop.add_callback(call)
    return result.result()


def _one_line(text) -> str:
    lines = [line.strip() for line in str(text).strip().splitlines() if line.strip()]
    return lines[0] if lines else ""


def describe_error(error: BaseException) -> str:
    return _one_line(f"{type(error).__name__}: {error}")


class _WorkerExits(logging.Filter):
    """Hands the nanny's lines about worker processes that did not exit cleanly (INFO, which
    LocalCluster silences) to every listening executor; lets through warnings and errors, but not
    the scheduler's on a heartbeat of a worker it removed (one leaving a loaded machine: a filter of
    its own on ``distributed.scheduler``).  One per process on ``distributed.nanny``."""

    PATTERN = re.compile(r"Worker process (\d+) (was killed by .*|exited with status \d+)")
    BENIGN = "Received heartbeat from unregistered worker"

    def __init__(self):
        super().__init__()
        self.listeners = []  # lists of (pid, what happened)

    def filter(self, record):
        if match := self.PATTERN.search(record.getMessage()):
            for listener in self.listeners:
                listener.append((int(match.group(1)), match.group(2)))
        return record.levelno >= logging.WARNING


def worker_log_filter() -> _WorkerExits:
    """The process's filter on the ``distributed.nanny`` logger (added the first time)."""
    logger = logging.getLogger("distributed.nanny")
    found = next((item for item in logger.filters if isinstance(item, _WorkerExits)), None)
    if found is None:
        found = _WorkerExits()
        logger.addFilter(found)
        logging.getLogger("distributed.scheduler").addFilter(lambda record: not record.getMessage().startswith(
            _WorkerExits.BENIGN))  # that one line only: the scheduler's others as Dask logs them
    return found


def _listen_to_worker_exits(listener: list):
    worker_log_filter().listeners.append(listener)
    logging.getLogger("distributed.nanny").setLevel(logging.INFO)


def _stop_listening(listener: list):
    watcher = worker_log_filter()
    watcher.listeners = [item for item in watcher.listeners if item is not listener]


class DaskExecutor:
    """The jobs of a plan as Dask tasks: on a LocalCluster of ``workers`` processes started here,
    or on the existing cluster whose scheduler is at ``scheduler``.  ``start()`` (or ``with``)
    connects and checks the workers; ``close()`` stops what it started."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None, *, plugins=(),
                 dashboard_address: str = DEFAULT_DASHBOARD, connect_timeout_s: float = CONNECT_TIMEOUT_S,
                 security=None):
        if (workers is None) == (scheduler is None):
            raise ExecutorError("give the Dask executor either a number of workers or a scheduler address")
        if workers is not None and workers < 1:
            raise ExecutorError(f"a LocalCluster needs at least 1 worker, not {workers}")
        self.workers = workers
        self.scheduler = check_scheduler_address(scheduler) if scheduler is not None else None
        self.plugins = tuple(plugins)  # distributed.WorkerPlugin instances, set up on every worker
        self.dashboard_address = dashboard_address
        self.security = security  # distributed.security.Security of a TLS cluster, or None
        self.connect_timeout_s = connect_timeout_s
        self.cluster = self.client = None
        self._exits = []  # (pid, what happened) of this LocalCluster's workers that did not exit cleanly

    # -- the cluster -------------------------------------------------------------------------
    def start(self) -> "DaskExecutor":
        distributed = import_distributed()
        try:
            if self.workers is not None:
                _listen_to_worker_exits(self._exits)
                with warnings.catch_warnings():  # "port 8787 is in use": the link printed says where it is
                    warnings.simplefilter("ignore")
                    self.cluster = distributed.LocalCluster(
                        n_workers=self.workers, threads_per_worker=1, processes=True,
                        resources={RESOURCE: 1}, memory_limit=0, dashboard_address=self.dashboard_address,
                        host=LOCAL_HOST)
                self.client = distributed.Client(self.cluster)
            else:
                try:
                    _probe(self.scheduler, self.connect_timeout_s)
                    options = {} if self.security is None else {"security": self.security}
                    self.client = distributed.Client(self.scheduler, timeout=self.connect_timeout_s, **options)
                except (OSError, TimeoutError) as error:
                    raise ExecutorError(f"cannot reach the Dask scheduler at {self.scheduler} ({_one_line(error)}): "
                                        f"start one with 'dask scheduler' (docs/cluster.md)") from None
            for plugin in self.plugins:
                try:
                    replies = self.client.register_plugin(plugin)
                except Exception as error:  # a worker's set-up raised
                    raise ExecutorError(f"a Dask worker cannot run PHRT: {describe_error(error)} (a worker needs "
                                        f"the Python with bpy and phrt: docs/cluster.md)") from None
                broken = {address: reply for address, reply in (replies or {}).items()
                          if isinstance(reply, dict) and reply.get("status") != "OK"}
                if broken:
                    address, reply = next(iter(broken.items()))
                    raise ExecutorError(f"Dask worker {address} cannot run PHRT: "
                                        f"{_one_line(reply.get('exception_text') or reply)} (a worker needs the "
                                        f"Python with bpy and phrt: docs/cluster.md)")
            workers = self.client.scheduler_info(n_workers=-1)["workers"]
            if not any(info.get("resources", {}).get(RESOURCE) for info in workers.values()):
                raise ExecutorError(
                    f"the Dask cluster at {self.client.scheduler.address} has no worker with the resource "
                    f"{RESOURCE}=1 ({len(workers)} workers): start workers with 'dask worker "
                    f"{self.client.scheduler.address} --nworkers 1 --nthreads 1 --resources {RESOURCE}=1'")
        except BaseException:
            self.close()
            raise
        return self

    @property
    def address(self) -> str:
        return self.client.scheduler.address

    @property
    def dashboard_link(self) -> str | None:
        try:
            return self.client.dashboard_link
        except Exception:  # a scheduler without its HTTP server
            return None

    @property
    def worker_exits(self) -> list:
        """(pid, what happened) of each LocalCluster worker process that did not exit with status 0
        (of every LocalCluster of this process while this one runs)."""
        return list(self._exits)

    def close(self):
        if self.cluster is not None and self.client is not None:
            # Workers first, their shutdown's heartbeat ERRORs quietened (a loaded machine logs them).
            try:
                self.client.run(lambda: logging.getLogger("distributed.worker").setLevel(logging.CRITICAL))
                self.cluster.scale(0)
                deadline = time.monotonic() + CLOSE_TIMEOUT_S
                while self.client.scheduler_info(n_workers=-1)["workers"] and time.monotonic() < deadline:
                    time.sleep(0.05)
            except Exception:  # closing anyway below
                pass
        if self.client is not None:
            self.client.close()
            self.client = None
        if self.cluster is not None:
            logging.getLogger("distributed.nanny").setLevel(logging.INFO)  # LocalCluster set it to WARNING
            self.cluster.close()
            self.cluster = None
        _stop_listening(self._exits)

    def __enter__(self):
        return self.start() if self.client is None else self

    def __exit__(self, *exc):
        self.close()

    # -- running a plan ----------------------------------------------------------------------

    def check_workers_see(self, plan_path: str):
        """ExecutorError unless every worker sees ``plan_path`` (the shared folder)."""
        seen = self.client.run(os.path.isfile, plan_path)
        blind = sorted(address for address, found in seen.items() if not found)
        if blind:
            raise ExecutorError(f"Dask worker {blind[0]} does not see {plan_path}: the sweep folder and the .blend "
                                f"must be on storage every worker sees at the same path (docs/cluster.md)")

    def run(self, plan_path, plan, execute, on_outcome=None) -> list:
        """Every job of ``plan`` as one task; returns the outcomes in plan order, calling
        ``on_outcome`` as each job ends.  A job whose task still failed after its retries (or
        whose workers kept dying) fails with its error's one-line message; jobs depending on a
        failed job are not run."""
        from distributed import as_completed
        if self.client is None:
            raise RuntimeError("DaskExecutor.run before start()")
        if self.cluster is not None:
            logging.getLogger("distributed.nanny").setLevel(logging.INFO)  # LocalCluster set it to WARNING
        plan_path = str(Path(plan_path).resolve())
        ordered = plan.in_dependency_order()
        self.check_workers_see(plan_path)
        tag = uuid.uuid4().hex[:8]
        futures = {}
        for job in ordered:
            dependencies = [futures[dependency] for dependency in job.depends_on]
            futures[job.id] = self.client.submit(run_job, execute, plan_path, job.id, *dependencies,
                                                 key=f"{job.id}-{tag}", resources={RESOURCE: 1}, retries=RETRIES,
                                                 pure=False)
        job_of = {future.key: job for job, future in zip(ordered, futures.values())}
        outcomes = {}
        try:
            for future in as_completed(list(futures.values())):
                job = job_of[future.key]
                outcome = self._outcome(job, future, futures)
                outcomes[job.id] = outcome
                if on_outcome is not None:
                    on_outcome(outcome)
        except BaseException:
            self.client.cancel(list(futures.values()))  # an existing cluster would go on otherwise
            raise
        finally:
            futures.clear()
        return [outcomes[job.id] for job in plan.jobs]

    @staticmethod
    def _outcome(job, future, futures) -> JobOutcome:
        if future.status == "finished":
            return future.result()
        if future.status == "cancelled":
            return JobOutcome(job.id, "failed", message="cancelled")
        dependencies = [(dependency, futures[dependency]) for dependency in job.depends_on]
        lost = [name for name, dependency in dependencies if dependency.status != "finished"]
        if lost:  # it never ran: a job it depends on raised (and was reported as failed)
            return JobOutcome(job.id, "failed", message=f"not run: {', '.join(lost)} failed")
        return JobOutcome(job.id, "failed", message=describe_error(future.exception()))


def make_executor(workers: int | None = None, scheduler: str | None = None, **options):
    """The executor for ``--workers`` / ``--scheduler``: ``plan.LocalExecutor`` when neither is given."""
    if workers is None and scheduler is None:
        from .plan import LocalExecutor
        return LocalExecutor()
    if workers is not None and scheduler is not None:
        raise ExecutorError("--workers and --scheduler both given: start a LocalCluster of N workers or use an "
                            "existing cluster, not both")
    return DaskExecutor(workers=workers, scheduler=scheduler, **options)
