"""The filter on Dask's loggers (phrt_addon/runs/executors.py): worker exits handed to the
listening executors, warnings let through, but not the scheduler's line on a heartbeat of a
worker it already removed (a worker leaving a loaded machine; it failed a sweep's clean-output
check once, 5 Dec 2026)."""
import logging

from phrt.phrt_addon.runs import executors


def _record(name, level, message):
    return logging.LogRecord(name, level, __file__, 1, message, None, None)


def test_the_benign_heartbeat_line_is_dropped_and_the_rest_let_through():
    exits = []
    watcher = executors.worker_log_filter()
    watcher.listeners.append(exits)
    scheduler = logging.getLogger("distributed.scheduler")
    try:
        assert not scheduler.filter(_record("distributed.scheduler", logging.WARNING,
                                            "Received heartbeat from unregistered worker 'tcp://127.0.0.1:4010'."))
        assert scheduler.filter(_record("distributed.scheduler", logging.WARNING, "Worker tcp://x failed to heartbeat"))
        # The scheduler's INFO lines are not the nanny filter's business (someone debugging keeps them).
        assert scheduler.filter(_record("distributed.scheduler", logging.INFO, "Register worker tcp://x"))
        assert watcher.filter(_record("distributed.nanny", logging.ERROR, "something else"))
        killed = _record("distributed.nanny", logging.INFO, "Worker process 123 was killed by signal 9")
        assert not watcher.filter(killed)
        assert exits == [(123, "was killed by signal 9")]
    finally:
        watcher.listeners.remove(exits)
