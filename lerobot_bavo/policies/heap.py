"""Keep the memory a training step frees in the process's heap (glibc), for the next step to reuse.

Why: a CPU training step allocates and frees tens of MB of tensors (activations, gradients). By default glibc
returns the top of its heap to the system once more than a few MB of it are free (`M_TRIM_THRESHOLD`, which it
raises to twice the largest block it has served from `mmap`), and serves blocks above its mmap threshold with
`mmap` and `munmap`: the next step then takes a page fault on every 4 KiB page it touches again and the kernel
zeroes each of them. Measured on the project's 2-core machines: ~4,000-5,000 page faults and ~9 ms of kernel
time per `cpu_fast` A-FAR step of 64 (one thread, ~215 ms), none once the heap keeps its memory. PyTorch has
no caching allocator on the CPU; its tuning guide recommends another allocator (jemalloc, tcmalloc) for the
same reason. Setting the two thresholds with `mallopt` does it in-process: blocks up to 32 MiB come from the
heap, and up to 1 GiB of free heap is kept. The cost is memory: the process keeps its peak heap.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import functools

# glibc's <malloc.h>
M_TRIM_THRESHOLD = -1
M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD = 32 << 20  # glibc's largest (HEAP_MAX_SIZE / 2 on 64-bit)
TRIM_THRESHOLD = 1 << 30


@functools.cache
def keep_freed_heap() -> bool:
    """Set glibc's mmap and trim thresholds (see the module docstring) once per process; False where the C
    library has no `mallopt` (not glibc) or refuses the values, which changes nothing."""
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    return bool(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD))
