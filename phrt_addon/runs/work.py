"""What a run did, recorded in its ``summary.json`` (``"work"``), so that a sweep run again redoes a
run whose work changed and skips it only when it is the same: the scene file's path and content
hash, the frame range, the resolution, the settings the run was asked for (mode, images,
budget, the scene setting overrides) and the project's version.

:func:`work_record` builds the record, :func:`work_difference` says in a few words what differs
between a recorded and a wanted record (None when they are the same).  Plain Python, no ``bpy``.
"""
from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

MANIFEST = Path(__file__).resolve().parents[2] / "blender_manifest.toml"
_VERSION = re.compile(r'^version\s*=\s*"([^"]+)"', re.MULTILINE)


def project_version() -> str:
    """The extension's version (``blender_manifest.toml``), "unknown" if it cannot be read."""
    try:
        found = _VERSION.search(MANIFEST.read_text(encoding="utf-8"))
    except OSError:
        return "unknown"
    return found.group(1) if found else "unknown"


def file_sha256(path) -> str | None:
    """The SHA-256 of a file's content, None when there is no such file."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    except OSError:
        return None
    return digest.hexdigest()


def _normal(value):
    """JSON-normal form (tuples as lists, floats to 6 significant digits as in summary.json)."""
    if isinstance(value, dict):
        return {str(key): _normal(item) for key, item in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_normal(item) for item in value]
    if isinstance(value, float):
        return float(format(value, ".6g"))
    return value


def work_record(scene_file, frames, resolution, *, mode, images, budget_ms=None, budget_at=None,
                overrides=None) -> dict:
    """The ``"work"`` of a run (``scene_file``: the .blend it rendered, None for an unsaved scene)."""
    path = None if not scene_file else str(Path(scene_file).resolve())
    return _normal({"scene_file": path, "scene_sha256": file_sha256(path) if path else None,
                    "frames": [int(frames[0]), int(frames[1])], "resolution": [int(r) for r in resolution],
                    "settings": {"mode": str(mode).upper(), "images": images, "budget_ms": budget_ms,
                                 "budget_at": budget_at, "overrides": dict(overrides or {})},
                    "phrt_version": project_version()})


def work_difference(recorded, wanted) -> str | None:
    """What differs between a run's recorded work and the wanted one, in a few words; None when
    they are the same.  A run without a record (an older PHRT) differs."""
    if not isinstance(recorded, dict):
        return "the run has no record of its work"
    recorded, wanted = _normal(recorded), _normal(wanted)

    def span(frames):
        return f"{frames[0]}-{frames[1]}" if isinstance(frames, list) and len(frames) == 2 else str(frames)

    if recorded.get("frames") != wanted.get("frames"):
        return f"frames {span(recorded.get('frames'))} -> {span(wanted.get('frames'))}"
    if recorded.get("resolution") != wanted.get("resolution"):
        size = (lambda r: "x".join(str(v) for v in r) if isinstance(r, list) else str(r))
        return f"resolution {size(recorded.get('resolution'))} -> {size(wanted.get('resolution'))}"
    if recorded.get("scene_file") != wanted.get("scene_file"):
        return f"scene file {recorded.get('scene_file')} -> {wanted.get('scene_file')}"
    if recorded.get("scene_sha256") != wanted.get("scene_sha256"):
        return "the scene file changed"
    if recorded.get("settings") != wanted.get("settings"):
        old, new = recorded.get("settings") or {}, wanted.get("settings") or {}
        keys = sorted(key for key in set(old) | set(new) if old.get(key) != new.get(key))
        return "settings changed: " + ", ".join(f"{key} {json.dumps(old.get(key))} -> {json.dumps(new.get(key))}"
                                                for key in keys)
    if recorded.get("phrt_version") != wanted.get("phrt_version"):
        return f"PHRT {recorded.get('phrt_version')} -> {wanted.get('phrt_version')}"
    return None
