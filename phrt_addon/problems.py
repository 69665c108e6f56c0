"""Problems of a replay (an object skipped, a material approximated...), each told once.

A snapshot lists what it skipped or approximated, frame after frame; a 120-frame
replay of a scene with a hair curve would say the same thing 120 times.
``ProblemLog`` remembers every message of a run with the frames it came up on:
``report()`` returns only the messages new to the run (the engine shows those as
warnings), and ``lines()`` / ``summary()`` give each message once with its count, like
a compiler's "N more like this" (the command line prints them, ``summary.json``
keeps them).  Plain Python, no ``bpy``.
"""
from __future__ import annotations


class ProblemLog:
    def __init__(self):
        self._frames = {}  # message -> [first frame, last frame, number of frames]

    def report(self, messages, frame=None) -> list:
        """Record this frame's ``messages``; returns those not seen before in the run."""
        fresh = []
        for message in dict.fromkeys(str(m) for m in messages):  # once per frame, in order
            entry = self._frames.get(message)
            if entry is None:
                self._frames[message] = [frame, frame, 1]
                fresh.append(message)
            else:
                entry[1] = frame
                entry[2] += 1
        return fresh

    def __len__(self):
        return len(self._frames)

    def summary(self) -> list:
        """[{"message", "frames", "first_frame", "last_frame"}] in the order they first came up."""
        return [{"message": message, "frames": count, "first_frame": first, "last_frame": last}
                for message, (first, last, count) in self._frames.items()]

    def lines(self, total_frames=None) -> list:
        """One line per message with how often it came up."""
        lines = []
        for item in self.summary():
            count = item["frames"]
            if total_frames and count == total_frames and count > 1:
                where = f"on all {count} frames"
            elif count > 1:
                where = f"on {count} frames ({item['first_frame']}-{item['last_frame']})"
            else:
                where = f"on frame {item['first_frame']}" if item["first_frame"] is not None else "once"
            lines.append(f"{item['message']} ({where})")
        return lines
