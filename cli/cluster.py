"""The Dask executor of ``phrt sweep``: its options checked (--workers, --scheduler, --dashboard,
--tls-*), started with its dashboard printed, and closed (docs/cluster.md)."""
from __future__ import annotations

import sys

from .blender_process import UserError


def executor_options(args):
    """The checked --workers/--scheduler/--dashboard/--tls-* options (UserError when they do not go
    together or a TLS file is missing; loads nothing)."""
    from ..phrt_addon.runs import executors
    try:
        return executors.executor_options(args.workers, args.scheduler, args.dashboard, args.tls_ca_file,
                                          args.tls_cert, args.tls_key)
    except executors.ExecutorError as error:
        raise UserError(str(error)) from None


def start_executor(workers, scheduler, options):
    """The executor of --workers / --scheduler, started (UserError when the cluster cannot run the
    plan), its dashboard printed."""
    from . import sweep as sweep_engine
    from ..phrt_addon.runs import executors
    try:
        executor = sweep_engine.make_executor(workers, scheduler, **options)
        if isinstance(executor, executors.DaskExecutor):
            executor.start()
    except executors.ExecutorError as error:
        raise UserError(str(error)) from None
    if isinstance(executor, executors.DaskExecutor):
        where = (f"a Dask LocalCluster of {workers} worker processes" if workers is not None
                 else f"the Dask cluster at {executor.address}")
        print(f"phrt: running on {where}; dashboard {executor.dashboard_link or 'not available'}", flush=True)
    return executor


def close_executor(executor):
    """Stop the executor (a Dask one: its cluster), warning about workers that did not exit cleanly."""
    close = getattr(executor, "close", None)
    if close is None:
        return
    close()
    for pid, what in executor.worker_exits:
        print(f"phrt: warning: Dask worker process {pid} {what}", file=sys.stderr)
