"""PHRT core: plain Python + numpy, no ``bpy``.

Scene snapshot, selection heuristic, ray tracer, compositor, metrics, run logs
and report live here, so that they are tested in milliseconds and reused by the
engine, the operators and the command line.
"""
