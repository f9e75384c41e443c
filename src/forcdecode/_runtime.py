"""Process-level runtime tuning, applied by the command-line entry point (not on library import).

glibc returns large blocks (> 128 kB, e.g. the FFT buffers of a 256×256×2 demag evaluation) to the
kernel on free and page-faults them in again on the next allocation; raising the mmap and trim
thresholds keeps them in the heap. Measured on the 256×256×2 field evaluation: 6.3 → 3.7 ms.
Equivalent to setting MALLOC_MMAP_THRESHOLD_/MALLOC_TRIM_THRESHOLD_ in the environment.

The BLAS (OpenBLAS under numpy and scipy) runs one thread: the loop's analysis makes ~10⁵ small
products and decompositions (64 × 64 families, a few thousand hysterons), where waking a second thread
costs more than it saves, and the loop's own worker processes (``core.parallel``) already use the
cores. Measured on the thermal candidate's family (``forc.thermal.coercivity_scaled_family``, 64
fields) beside other jobs on 2 cores: 7 ms with one BLAS thread, 125 ms with two. The tests run so too
(tests/conftest.py).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import sys

_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3


def tune_allocator(mmap_threshold: int = 256 << 20, trim_threshold: int = 512 << 20) -> bool:
    """Raise glibc's mmap/trim thresholds; returns False where that is not possible (not glibc)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, mmap_threshold)) and bool(libc.mallopt(_M_TRIM_THRESHOLD, trim_threshold))
    except (OSError, AttributeError):
        return False


def limit_blas_threads(threads: int = 1) -> bool:
    """Limit the BLAS libraries loaded in this process to ``threads`` threads (``threadpoolctl``); False
    where threadpoolctl cannot be imported."""
    try:
        from threadpoolctl import threadpool_limits  # imported here: this module is imported by the CLI first
    except ImportError:
        return False
    threadpool_limits(limits=threads, user_api="blas")
    return True
