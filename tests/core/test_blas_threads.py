"""numpy's OpenBLAS held to one thread inside the block and given back its count after."""
import numpy as np

from phrt.phrt_addon import blas_threads

blas = blas_threads.BlasThreads()


def test_numpys_openblas_is_found_limited_and_restored():
    before = blas.thread_counts()
    # numpy's wheels (the pinned requirement) link OpenBLAS: it must be found here.
    assert before, "no OpenBLAS found among the loaded libraries"
    with blas.limited(1):
        assert blas.thread_counts() == [1] * len(before)
        with blas.limited(1):  # nested: the inner block restores what it found (1)
            np.ones((5000, 3)) @ np.eye(3)
        assert blas.thread_counts() == [1] * len(before)
    assert blas.thread_counts() == before


def test_a_limit_is_restored_when_the_block_raises():
    before = blas.thread_counts()
    try:
        with blas.limited(1):
            raise KeyError("x")
    except KeyError:
        pass
    assert blas.thread_counts() == before


def test_only_blas_libraries_are_listed():
    for path in blas_threads.loaded_libraries():
        assert "blas" in path.rsplit("/", 1)[-1].lower()
