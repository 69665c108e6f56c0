"""The command line's argument rules, shared by its commands: counts and numbers (argparse
types), a resolution, the budget fractions of ``--budget-at F[,F...]``, an output folder, and a
replay's own arguments (mode, images, budget, budget-at, frame range), which only
``engine/runs/replay.check_input`` checks: the replay asks the same of every caller.
Bad input raises ``UserError`` (one line: what is wrong and how to fix it), before anything is
loaded or written."""
from __future__ import annotations

import argparse
import math

from .blender_process import UserError


def count(text):
    """An argparse type: a whole number >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{value} is not a count >= 1")
    return value


def number(text):
    """An argparse type: a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"'{text}' is not a finite number")
    return value


def check_replay_input(**arguments):
    """UserError unless ``engine/runs/replay.check_input(**arguments)`` accepts them."""
    from ..engine.runs import camera_path, replay
    try:
        replay.check_input(**arguments)
    except camera_path.ReplayError as error:
        raise UserError(str(error)) from None


def budget_fractions(text) -> list:
    """'0.5,0.25' -> [0.25, 0.5] (sorted, each once): the budgets of ``--budget-at F[,F...]``."""
    fractions = []
    for part in str(text).split(","):
        try:
            value = number(part.strip())
        except argparse.ArgumentTypeError as error:
            raise UserError(f"--budget-at: {error}; give fractions like 0.25,0.5") from None
        check_replay_input(budget_at=value)
        fractions.append(value)
    return sorted(set(fractions))


def parse_resolution(text):
    """'640x480' -> (640, 480); None stays None (the scene's own)."""
    if text is None:
        return None
    parts = text.lower().split("x")
    try:
        width, height = (int(p) for p in parts)
    except ValueError:
        raise UserError(f"malformed resolution '{text}': use WxH, e.g. --resolution 640x480") from None
    if width <= 0 or height <= 0 or width > 16384 or height > 16384:
        raise UserError(f"resolution '{text}' is out of range: width and height must be 1-16384 pixels")
    return width, height


def check_output_dir(path):
    """UserError unless ``path`` can be created and written (creates nothing)."""
    from ..phrt_addon.runs.folder import output_dir_problem
    problem = output_dir_problem(path)
    if problem is not None:
        raise UserError(problem)
