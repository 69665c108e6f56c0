"""4x4 placement matrices of the sample scenes' parts (translation, rotations, scale, their
composition), plain numpy."""
from __future__ import annotations

import math

import numpy as np


def translation(x: float, y: float, z: float) -> np.ndarray:
    matrix = np.eye(4)
    matrix[:3, 3] = (x, y, z)
    return matrix


def rotation_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    matrix = np.eye(4)
    matrix[:2, :2] = ((c, -s), (s, c))
    return matrix


def rotation_x(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    matrix = np.eye(4)
    matrix[1:3, 1:3] = ((c, -s), (s, c))
    return matrix


def rotation_y(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    matrix = np.eye(4)
    matrix[0, 0], matrix[0, 2], matrix[2, 0], matrix[2, 2] = c, s, -s, c
    return matrix


def scale(x: float, y: float, z: float) -> np.ndarray:
    return np.diag((x, y, z, 1.0))


def compose(*matrices: np.ndarray) -> np.ndarray:
    """compose(A, B, C) applies C first, then B, then A."""
    result = np.eye(4)
    for matrix in matrices:
        result = result @ matrix
    return result


# --------------------------------------------------------------------------
# Orientation checks (used by the tests and by the convex primitives)
