"""What may stop or disturb a replay from outside Blender's own API: SIGINT and SIGTERM (stopping
between frames) and the text Blender's C code writes on stderr while a frame renders."""
from __future__ import annotations

import contextlib
import os
import signal
import sys
import tempfile
import threading


@contextlib.contextmanager
def stop_on_signals(received: list):
    """SIGINT and SIGTERM stop a replay between frames (the frame being rendered is finished,
    written and logged, then ``summary.json`` says the run is partial): their names are appended
    to ``received``.  A second signal acts as usual.  Only in the main thread (signal handlers
    live there); elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    defaults = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: signal.SIG_DFL}
    previous = {}

    def handler(signum, _frame):
        received.append(signal.Signals(signum).name)
        for number, default in defaults.items():
            signal.signal(number, default)

    for number in defaults:
        previous[number] = signal.signal(number, handler)
    try:
        yield
    finally:
        for number, before in previous.items():
            signal.signal(number, before)


class CapturedStderr:
    """What Blender's C code wrote on stderr while rendering a frame: forwarded as it was once
    the frame is known good, or summed up in the one-line error when it is not."""

    def __init__(self):
        self.text = ""

    def reason(self) -> str:
        """The last line that names an error, shortened (e.g. OpenEXR's 'File too large')."""
        lines = [line.strip() for line in self.text.splitlines()
                 if "error" in line.lower() and not line.startswith("EGL")]  # EGL_BAD_MATCH is harmless noise
        if not lines:
            return ""
        line = lines[-1]
        return line.rsplit(". ", 1)[-1][:120] if ". " in line else line[:120]

    def forward(self):
        if self.text:
            sys.stderr.write(self.text)
            sys.stderr.flush()


@contextlib.contextmanager
def captured_stderr():
    """Route file descriptor 2 (where Blender's C code writes) to a temporary file while the
    block runs; the text is kept on the yielded object."""
    captured = CapturedStderr()
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            yield captured
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            captured.text = capture.read().decode(errors="replace")
