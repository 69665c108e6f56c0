"""Rows of an array at given indices, at numpy's best speed on this kind of machine.

``np.take`` of (n, 3) rows is several times faster than fancy indexing, but only from a
C-contiguous array: given a strided view (the read-back G-buffer's positions and normals are
``[..., :3]`` views of (h, w, 4) images, ``engine/gpu/readback.py``) it first copies the whole
array.  At 320x240 that copy is 0.55 ms, against 0.02 ms for taking 4,400 rows of a contiguous
array and 0.06 ms for fancy indexing the view (docs/platform-notes.md).
"""
from __future__ import annotations

import numpy as np


def take_rows(array: np.ndarray, index) -> np.ndarray:
    """``array[index]`` along the first axis for an integer ``index`` array: ``np.take`` from a
    C-contiguous array, fancy indexing from a strided one (no copy of the whole array)."""
    if array.flags.c_contiguous:
        return np.take(array, index, axis=0)
    return array[np.asarray(index, np.intp)]


def compress_rows(mask: np.ndarray, array: np.ndarray) -> np.ndarray:
    """``array[mask]`` along the first axis (``mask`` of its length): ``np.compress`` from a
    C-contiguous array, a boolean index into a strided one."""
    if array.flags.c_contiguous:
        return np.compress(mask, array, axis=0)
    return array[mask]
