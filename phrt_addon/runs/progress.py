"""The progress line of a plan's run on a terminal (``phrt sweep``).  Plain Python, no ``bpy``."""
from __future__ import annotations

import time


class Progress:
    """The line ``jobs 3/10 done (1 skipped, 0 failed), ETA 40 s`` on ``stream`` when it is a terminal
    (nothing otherwise).  The ETA is the time per job that ran so far (skipped jobs left out,
    several workers counted in: wall time over jobs done) times the jobs left."""

    def __init__(self, total: int, stream, clock=time.perf_counter):
        self.total = total
        self.stream = stream
        self.active = bool(getattr(stream, "isatty", lambda: False)())
        self.clock = clock
        self.started = clock()
        self.finished = self.skipped = self.failed = 0
        self.detail = ""  # what the jobs under way have done (a lockstep group's frames), or ""

    def eta_s(self) -> float | None:
        ran = self.finished - self.skipped
        if ran <= 0:
            return None
        return (self.clock() - self.started) / ran * (self.total - self.finished)

    def line(self) -> str:
        eta = self.eta_s()
        text = f"jobs {self.finished}/{self.total} done ({self.skipped} skipped, {self.failed} failed)"
        if self.finished < self.total:
            text += f", ETA {eta:.0f} s" if eta is not None else ", ETA --"
            if self.detail:
                text += f"; {self.detail}"
        return text

    def under_way(self, detail: str):
        """Show ``detail`` (what the jobs under way have done so far) on the line."""
        self.detail = detail
        self.show()

    def update(self, outcome):
        self.detail = ""
        self.finished += 1
        self.skipped += outcome.status == "skipped"
        self.failed += outcome.status == "failed"
        self.show()

    def show(self):
        if self.active:
            self.stream.write("\r\033[K  " + self.line() + ("\n" if self.finished >= self.total else ""))
            self.stream.flush()

    def clear(self):
        """Wipe the line (before printing something else on the terminal)."""
        if self.active and self.finished < self.total:
            self.stream.write("\r\033[K")
            self.stream.flush()
