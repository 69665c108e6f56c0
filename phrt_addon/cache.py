"""``BoundedCache``: the one cache class of PHRT.  A mapping that keeps at most ``limit``
entries, dropping the least recently used (``on_evict`` is told, e.g. to close an Embree
scene).  Every cache that outlives a frame is one of these, owned by the engine's session
(``engine/session.py``) or by a ``FrameRenderer``."""
from __future__ import annotations

from collections import OrderedDict
from typing import Callable


class BoundedCache:
    def __init__(self, limit: int, on_evict: Callable[[object, object], None] | None = None):
        if limit < 1:
            raise ValueError(f"a cache holds at least one entry, not {limit}")
        self.limit = int(limit)
        self.on_evict = on_evict
        self._entries = OrderedDict()

    def get(self, key, default=None):
        if key not in self._entries:
            return default
        self._entries.move_to_end(key)
        return self._entries[key]

    def put(self, key, value):
        if key in self._entries:
            self._entries.move_to_end(key)
        self._entries[key] = value
        while len(self._entries) > self.limit:
            old_key, old_value = self._entries.popitem(last=False)
            if self.on_evict is not None:
                self.on_evict(old_key, old_value)
        return value

    def clear(self):
        """Drop every entry (``on_evict`` is told of each)."""
        while self._entries:
            key, value = self._entries.popitem(last=False)
            if self.on_evict is not None:
                self.on_evict(key, value)

    def values(self):
        return list(self._entries.values())

    def __contains__(self, key):
        return key in self._entries

    def __len__(self):
        return len(self._entries)
