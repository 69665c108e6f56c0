"""numpy's BLAS kept to one thread while PHRT renders.

numpy's wheels link OpenBLAS, which runs a matrix product of more than a few thousand
rows on every core and then keeps its worker threads spinning, waiting for the next one.
In a render those cores belong to the GPU driver (llvmpipe's rasterizer threads, on a
machine without a GPU), Embree and Blender: measured on atrium/path1 (2 cores), a raster
frame's p95 fell from 114-121 ms to 88-92 ms with one BLAS thread (mean 83-91 -> 79-80
ms), and a 4x4 ``np.linalg.inv`` inside a frame took 1.3 ms instead of 5 us.  PHRT's own
products are (N, 3) @ (3, 3): memory-bound, no faster on two threads.

``BlasThreads().limited(1)`` sets the thread count of every OpenBLAS numpy loaded (found among the
process's shared libraries, as threadpoolctl does) and restores what it found on exit, so
other add-ons in the same Blender keep theirs.  Without OpenBLAS (Accelerate on macOS, an
MKL build) it changes nothing.  Plain Python (ctypes); no ``bpy``.
"""
from __future__ import annotations

import contextlib
import ctypes
import os
import sys

# OpenBLAS exports its thread functions under these names (a 64-bit-integer build suffixes
# "64_"; numpy 2's scipy-openblas adds a prefix).
_PREFIXES = ("openblas", "scipy_openblas")
_SUFFIXES = ("", "64_")

def loaded_libraries() -> list[str]:
    """Paths of the shared libraries loaded in this process whose name mentions BLAS."""
    paths: set[str] = set()
    if sys.platform.startswith("linux"):
        try:
            with open("/proc/self/maps", encoding="utf-8", errors="replace") as maps:
                for line in maps:
                    fields = line.split(maxsplit=5)
                    if len(fields) == 6 and fields[5].startswith("/"):
                        paths.add(fields[5].strip())
        except OSError:
            return []
    elif sys.platform == "darwin":
        try:
            dyld = ctypes.CDLL(None)
            dyld._dyld_get_image_name.restype = ctypes.c_char_p
            for index in range(dyld._dyld_image_count()):
                name = dyld._dyld_get_image_name(index)
                if name:
                    paths.add(name.decode("utf-8", "replace"))
        except (OSError, AttributeError):
            return []
    elif sys.platform == "win32":
        try:
            psapi, kernel = ctypes.WinDLL("Psapi.dll"), ctypes.WinDLL("kernel32")
            process = kernel.GetCurrentProcess()
            modules = (ctypes.c_void_p * 1024)()
            needed = ctypes.c_ulong()
            if psapi.EnumProcessModulesEx(process, modules, ctypes.sizeof(modules), ctypes.byref(needed), 3):
                name = ctypes.create_unicode_buffer(1024)
                for module in modules[:needed.value // ctypes.sizeof(ctypes.c_void_p)]:
                    if module and psapi.GetModuleFileNameExW(process, ctypes.c_void_p(module), name, 1024):
                        paths.add(name.value)
        except (OSError, AttributeError):
            return []
    return sorted(path for path in paths if "blas" in os.path.basename(path).lower())


class BlasThreads:
    """The OpenBLAS libraries numpy loaded, found once (the engine session keeps one)."""

    def __init__(self):
        self._controls = None

    def controls(self) -> list:
        """[(get, set)] of every OpenBLAS loaded (numpy imported first)."""
        if self._controls is None:
            self._controls = _find_controls()
        return self._controls

    def thread_counts(self) -> list[int]:
        """The thread count of each OpenBLAS found (empty: none)."""
        return [get() for get, _ in self.controls()]

    @contextlib.contextmanager
    def limited(self, threads: int = 1):
        """Every OpenBLAS found runs at most ``threads`` threads inside the block; each gets
        back the count it had after it."""
        found = [(get(), set_) for get, set_ in self.controls()]
        for count, set_ in found:
            if count > threads:
                set_(int(threads))
        try:
            yield
        finally:
            for count, set_ in found:
                if count > threads:
                    set_(count)


def _find_controls() -> list:
    import numpy  # noqa: F401  (loads the BLAS numpy links)
    controls = []
    for path in loaded_libraries():
        try:
            library = ctypes.CDLL(path)
        except OSError:
            continue
        for prefix in _PREFIXES:
            for suffix in _SUFFIXES:
                get = getattr(library, f"{prefix}_get_num_threads{suffix}", None)
                set_ = getattr(library, f"{prefix}_set_num_threads{suffix}", None)
                if get is not None and set_ is not None:
                    get.restype, get.argtypes = ctypes.c_int, []
                    set_.restype, set_.argtypes = None, [ctypes.c_int]
                    controls.append((get, set_))
                    break
            else:
                continue
            break
    return controls
