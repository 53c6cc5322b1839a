"""One thread for the OpenBLAS that numpy (and scipy) loaded, for the duration of a fit.

numpy's products in a fit are small (20000 x 3 points by a plane's normal, 1200 times over in the bounding
planes' RANSAC; 2 M voxel centres by a 3 x 3 rotation): a second OpenBLAS thread only adds its wake-ups, and on
a loaded machine each waits for a core. cave-chair 128 px bounding planes, load 8-10: 9.3-19.7 s wall (0.9-2.4
CPU-s) with numpy's default threads, 1.5-3.6 s (0.35-0.94 CPU-s) with one, the same planes to the bit (session
17, issue 11); 1000 such products: 3.0-12.4 s wall against 0.08-0.12 s. Each product's dot products are the
same with any thread count (the threads split its rows). torch keeps its own `--threads`.

Linux only (the loaded libraries are read from /proc/self/maps, as threadpoolctl does); elsewhere a no-op.
"""

from __future__ import annotations

import contextlib
import ctypes
import os

#: symbol names of OpenBLAS builds: numpy's wheels (64-bit integers, suffix 64_) and scipy's (prefix scipy_)
_NAMES = [(f"{p}_get_num_threads{s}", f"{p}_set_num_threads{s}")
          for p in ("openblas", "scipy_openblas") for s in ("", "64_", "_64_")]


def _loaded_openblas() -> list:
    """(get, set) ctypes functions of each OpenBLAS library already loaded in this process."""
    if not hasattr(os, "RTLD_NOLOAD"):
        return []
    try:
        with open("/proc/self/maps") as maps:
            paths = sorted({line.split()[-1] for line in maps if "openblas" in line.lower() and "/" in line})
    except OSError:
        return []
    found = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=os.RTLD_NOLOAD)
        except OSError:
            continue
        for get_name, set_name in _NAMES:
            get, put = getattr(lib, get_name, None), getattr(lib, set_name, None)
            if get is not None and put is not None:
                get.restype, put.argtypes = ctypes.c_int, [ctypes.c_int]
                found.append((get, put))
                break
    return found


@contextlib.contextmanager
def single_threaded_blas():
    """numpy's (and an already loaded scipy's) OpenBLAS on one thread inside the block, as before after it."""
    import numpy  # noqa: F401 - loads numpy's OpenBLAS

    libs = _loaded_openblas()
    before = [get() for get, _ in libs]
    for _, put in libs:
        put(1)
    try:
        yield
    finally:
        for (_, put), n in zip(libs, before):
            put(n)
