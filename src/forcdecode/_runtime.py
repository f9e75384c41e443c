"""Process-level runtime tuning, applied by the command-line entry point (not on library import).

glibc returns large blocks (> 128 kB, e.g. the FFT buffers of a 256×256×2 demag evaluation) to the
kernel on free and page-faults them in again on the next allocation; raising the mmap and trim
thresholds keeps them in the heap. Measured on the 256×256×2 field evaluation: 6.3 → 3.7 ms.
Equivalent to setting MALLOC_MMAP_THRESHOLD_/MALLOC_TRIM_THRESHOLD_ in the environment.
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
