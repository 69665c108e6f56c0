"""Runs driven through Blender: camera path replays, sweeps, the oracle's renders, budget calibration,
and the tagging advice (``advise.py``; ``item_measure.py``: one subset traced and measured, the
function the oracle and the advice share)."""
