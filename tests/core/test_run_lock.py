"""One writer per run folder (phrt_addon/runs/lock.py) and whole-or-nothing files (runs/atomic.py),
with real processes: a live owner refuses, a SIGKILLed one is taken over."""
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from phrt.phrt_addon.runs import atomic, lock

HOLDER = ("import sys, time; from phrt.phrt_addon.runs import lock; held = lock.acquire(sys.argv[1]); "
          "print('locked', flush=True); time.sleep(600)")


@pytest.fixture
def holder(tmp_path):
    process = subprocess.Popen([sys.executable, "-c", HOLDER, str(tmp_path / "run")], stdout=subprocess.PIPE,
                               text=True)
    assert process.stdout.readline().strip() == "locked"
    yield process
    if process.poll() is None:
        process.kill()
    process.wait()


def test_a_live_owner_refuses_a_second_writer_in_one_line(tmp_path, holder):
    with pytest.raises(lock.LockHeld) as refused:
        lock.acquire(tmp_path / "run")
    message = str(refused.value)
    assert "\n" not in message and f"process {holder.pid} on {lock.host_name()}" in message


def test_a_killed_owners_lock_is_taken_over(tmp_path, holder):
    holder.send_signal(signal.SIGKILL)
    holder.wait()
    taken = lock.acquire(tmp_path / "run")
    assert taken.took_over is not None and taken.took_over.pid == holder.pid
    assert taken.held and lock.read_owner(tmp_path / "run" / lock.LOCK_NAME).pid == os.getpid()
    taken.release()
    assert not (tmp_path / "run" / lock.LOCK_NAME).exists()


def test_a_reused_pid_is_not_taken_for_the_owner(tmp_path):
    """The lock names this (live) pid but another process start time: its writer is gone."""
    folder = tmp_path / "run"
    folder.mkdir()
    start = lock.process_start(os.getpid())
    if start is None:
        pytest.skip("no /proc/<pid>/stat on this platform")
    (folder / lock.LOCK_NAME).write_text(json.dumps(
        {"host": lock.host_name(), "pid": os.getpid(), "started": time.time() - 100, "process_start": start - 1}))
    taken = lock.acquire(folder)
    assert taken.took_over.process_start == start - 1


def test_another_hosts_lock_is_held_and_the_message_says_how_to_free_it(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / lock.LOCK_NAME).write_text(json.dumps({"host": "elsewhere", "pid": 1, "started": time.time()}))
    with pytest.raises(lock.LockHeld, match="if it is gone, delete"):
        lock.acquire(folder)


def test_release_leaves_a_lock_that_is_no_longer_this_ones(tmp_path):
    taken = lock.acquire(tmp_path / "run")
    (tmp_path / "run" / lock.LOCK_NAME).write_text(json.dumps({"host": "elsewhere", "pid": 1, "started": 0.0}))
    taken.release()
    assert lock.read_owner(tmp_path / "run" / lock.LOCK_NAME).host == "elsewhere"


def test_tags_name_dead_writers_only_on_this_host(tmp_path):
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    assert lock.tag_is_dead(lock.owner_tag(process.pid))
    assert not lock.tag_is_dead(lock.owner_tag())
    assert not lock.tag_is_dead(f"elsewhere-{process.pid}")
    assert not lock.tag_is_dead("not a tag")
    assert lock.parse_tag(lock.owner_tag(42)) == (lock.host_name(), 42)


def test_atomic_files_appear_whole_and_a_failed_write_leaves_nothing(tmp_path):
    target = tmp_path / "report.md"
    atomic.write_text(target, "old")
    with pytest.raises(RuntimeError):
        with atomic.atomic_open(target) as handle:
            handle.write("new, half")
            raise RuntimeError("the writer failed")
    assert target.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["report.md"]


def test_dead_writers_temporaries_are_found_live_ones_are_not(tmp_path):
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    dead = tmp_path / f"summary.json{atomic.TEMPORARY_MARK}{lock.owner_tag(process.pid)}"
    live = atomic.temporary_path(tmp_path / "summary.json")
    other = tmp_path / f"summary.json{atomic.TEMPORARY_MARK}elsewhere-{process.pid}"
    for path in (dead, live, other):
        path.write_text("")
    assert atomic.dead_temporaries(tmp_path) == [dead]
