"""One writer per run folder: the lock file ``.phrt-lock`` (host, pid, start time), and who owns
a temporary name.

:func:`acquire` creates ``FOLDER/.phrt-lock`` holding this process's host, pid, the time it
took the lock and the process's own start time (``/proc/<pid>/stat`` on Linux, so that a
reused pid is not taken for the writer).  The file is written under a temporary name and
linked to its final name, so a lock is never seen half-written.  While the owner lives,
:func:`acquire` raises :class:`LockHeld` (one line: who holds it since when); a lock whose owner
is dead (same host, no such process) is taken over.  The owner on another host cannot be
checked from here: its lock is held until removed by hand (the message says so).

:func:`owner_tag` is the ``host-pid`` part of every temporary name a writer uses
(``summary.json.tmp-HOST-PID``, ``.0001.partial-HOST-PID.exr``, ``.JOB.partial-HOST-PID``), and
:func:`tag_is_dead` says whether the writer a tag names is gone (same host, no such process):
only then may a clean-up remove what it left.  Plain Python, no ``bpy``.
"""
from __future__ import annotations

import json
import os
import re
import socket
import sys
import time
from dataclasses import dataclass
from pathlib import Path

LOCK_NAME = ".phrt-lock"
_UNSAFE = re.compile(r"[^A-Za-z0-9_]")


class LockHeld(ValueError):
    """The folder has a live writer: the message (one line) names it."""


def host_name() -> str:
    """This host's name as it appears in lock files and temporary names (letters, digits and _ only)."""
    return _UNSAFE.sub("_", socket.gethostname() or "host")


def owner_tag(pid: int | None = None) -> str:
    """``HOST-PID`` of this process (or of ``pid`` on this host)."""
    return f"{host_name()}-{os.getpid() if pid is None else int(pid)}"


def parse_tag(tag: str):
    """(host, pid) of a ``HOST-PID`` tag, or None when it is not one."""
    host, _, pid = str(tag).rpartition("-")
    if not host or not pid.isdigit():
        return None
    return host, int(pid)


def process_start(pid: int):
    """The start time of process ``pid`` in clock ticks since boot (Linux), else None."""
    try:
        with open(f"/proc/{int(pid)}/stat", encoding="ascii", errors="replace") as handle:
            text = handle.read()
    except OSError:
        return None
    fields = text[text.rfind(")") + 2:].split()
    try:
        return int(fields[19])  # field 22 of stat(5), counted after the command name
    except (IndexError, ValueError):
        return None


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists on this host (a zombie counts as dead)."""
    pid = int(pid)
    if pid <= 0:
        return False
    if sys.platform == "win32":
        return _windows_pid_alive(pid)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # it exists, owned by another user
    except OSError:
        return False
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as handle:
            state = handle.read().rpartition(")")[2].split()[0]
        return state not in ("Z", "X")
    except (OSError, IndexError):
        return True


def _windows_pid_alive(pid: int) -> bool:
    """OpenProcess + GetExitCodeProcess (os.kill(pid, 0) would terminate the process on Windows)."""
    import ctypes
    kernel32 = ctypes.windll.kernel32
    handle = kernel32.OpenProcess(0x1000, False, pid)  # PROCESS_QUERY_LIMITED_INFORMATION
    if not handle:
        return False
    try:
        code = ctypes.c_ulong()
        return bool(kernel32.GetExitCodeProcess(handle, ctypes.byref(code))) and code.value == 259  # STILL_ACTIVE
    finally:
        kernel32.CloseHandle(handle)


def tag_is_dead(tag: str) -> bool:
    """Whether the writer named by a ``HOST-PID`` tag is known to be gone: on this host, with no
    such process.  A tag of another host, or not a tag at all, is not known dead."""
    parsed = parse_tag(tag)
    if parsed is None:
        return False
    host, pid = parsed
    return host == host_name() and not pid_alive(pid)


@dataclass
class Owner:
    host: str
    pid: int
    started: float  # time.time() when the lock was taken
    process_start: int | None = None

    @classmethod
    def me(cls) -> "Owner":
        return cls(host_name(), os.getpid(), time.time(), process_start(os.getpid()))

    def to_json(self) -> dict:
        return {"host": self.host, "pid": self.pid, "started": self.started,
                "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(self.started)),
                "process_start": self.process_start}

    @classmethod
    def from_json(cls, data) -> "Owner":
        return cls(str(data["host"]), int(data["pid"]), float(data["started"]),
                   None if data.get("process_start") is None else int(data["process_start"]))

    def is_alive(self) -> bool:
        """True unless it is known dead: another host's owner counts as alive."""
        if self.host != host_name():
            return True
        if not pid_alive(self.pid):
            return False
        if self.process_start is not None:
            now = process_start(self.pid)
            if now is not None and now != self.process_start:
                return False  # the pid was reused by another process
        return True

    def same_as(self, other: "Owner") -> bool:
        return (self.host, self.pid, self.started) == (other.host, other.pid, other.started)

    def describe(self) -> str:
        when = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(self.started))
        return f"process {self.pid} on {self.host} since {when}"


def read_owner(path) -> Owner | None:
    """The owner written in a lock file, None when there is none or it cannot be read."""
    try:
        return Owner.from_json(json.loads(Path(path).read_text(encoding="utf-8")))
    except (OSError, ValueError, KeyError, TypeError):
        return None


class RunLock:
    """A held lock of one folder; :meth:`release` removes the file if it is still this one's."""

    def __init__(self, path: Path, owner: Owner, took_over: Owner | None = None):
        self.path, self.owner, self.took_over = path, owner, took_over

    @property
    def held(self) -> bool:
        found = read_owner(self.path)
        return found is not None and found.same_as(self.owner)

    def release(self):
        if self.held:
            try:
                self.path.unlink()
            except OSError:
                pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()
        return False


def _create(path: Path, owner: Owner) -> bool:
    """Create the lock file with its whole content at once; False if one exists."""
    temporary = path.with_name(f"{path.name}.tmp-{owner_tag()}")
    temporary.write_text(json.dumps(owner.to_json()) + "\n", encoding="utf-8")
    try:
        os.link(temporary, path)  # fails if the lock exists: never a half-written lock
        return True
    except FileExistsError:
        return False
    except (AttributeError, NotImplementedError, PermissionError):
        pass  # a file system without hard links: create it in place
    finally:
        temporary.unlink(missing_ok=True)
    try:
        descriptor = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        return False
    with os.fdopen(descriptor, "w", encoding="utf-8") as handle:
        handle.write(json.dumps(owner.to_json()) + "\n")
    return True


def acquire(folder) -> RunLock:
    """Lock ``folder`` (created if missing) for this process; :class:`LockHeld` while another
    live process holds it, a dead owner's lock taken over (``RunLock.took_over``)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / LOCK_NAME
    me = Owner.me()
    took_over = None
    for _ in range(20):
        if _create(path, me):
            return RunLock(path, me, took_over)
        owner = read_owner(path)
        if owner is None:
            if not path.exists():
                continue
            # Unreadable (written by hand, or damaged): it names no live writer; replace it.
            grave = path.with_name(f"{path.name}.dead-{owner_tag()}")
            try:
                os.replace(path, grave)
                grave.unlink()
            except FileNotFoundError:
                pass
            continue
        if owner.is_alive():
            if owner.host == me.host and owner.pid == me.pid:
                raise LockHeld(f"this process already writes '{folder}'")
            extra = "" if owner.host == me.host else f" (if it is gone, delete {path})"
            raise LockHeld(f"'{folder}' is being written by {owner.describe()}: wait for it to end or give "
                           f"another --out{extra}")
        # Dead owner: move its lock aside, checking that what moved is still that dead owner's.
        grave = path.with_name(f"{path.name}.dead-{owner_tag()}")
        try:
            os.replace(path, grave)
        except FileNotFoundError:
            continue
        moved = read_owner(grave)
        if moved is not None and not moved.same_as(owner):  # another writer took it over meanwhile
            try:
                os.link(grave, path)
            except OSError:
                pass
            grave.unlink(missing_ok=True)
            raise LockHeld(f"'{folder}' is being written by {moved.describe()}: wait for it to end or give "
                           f"another --out")
        grave.unlink(missing_ok=True)
        took_over = owner
    raise LockHeld(f"could not lock '{folder}': its lock file keeps changing")
