"""Runs driven through Blender: camera path replays, sweeps, the oracle's renders, budget calibration."""
