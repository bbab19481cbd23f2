"""Worker processes that die with their parent, and one writer per output folder.

Why: after a `kill -9` of `bavo-eval` or `bavo-collect`, their pool workers (each holding a MuJoCo
model, GL contexts and torch: ~0.6-1.2 GB) were re-parented to PID 1 and lived on, and so did the
multiprocessing resource tracker, whose pipe they kept open. Each worker now watches its parent and
exits within a second of losing it (a parent-death signal alone is tied to the thread that spawned
the worker and would also fire when a short-lived spawning thread ends, so a poll is used). The watch
starts in the pool initializer, so a spawned worker killed while it is still importing (seconds on an
idle machine, minutes on a saturated one) exits as soon as its imports finish. Two runs on one output folder
(or one dataset, reached through a symlink) corrupted each other; an advisory lock on the *resolved* path
refuses the second. Pool workers (`bavo-collect`'s and `bavo-eval`'s) and `bavo-collect` itself also keep
freed heap memory for reuse (`retain_freed_memory`): their per-episode arrays are large enough that glibc
would otherwise map and zero them afresh every episode.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
import time
from pathlib import Path

POLL_S = 0.5
WATCH_THREAD_NAME = "bavo-watch"


def exit_with_parent(parent: int | None = None, poll_s: float = POLL_S) -> None:
    """In a worker process: exit at once (`os._exit`) when the parent process `parent` is gone.

    `parent` is the pid the parent passed in (pool `initargs`): a spawned worker imports for seconds before
    its initializer runs, and a parent killed meanwhile would otherwise leave it re-parented already, with
    nothing left to compare against."""
    parent = os.getppid() if parent is None else int(parent)
    if os.getppid() != parent:
        os._exit(1)

    def watch() -> None:
        try:  # name the OS thread (visible in /proc/<pid>/task/*/comm) so tools and tests can see the watch
            import ctypes

            ctypes.CDLL("libc.so.6").prctl(15, WATCH_THREAD_NAME.encode(), 0, 0, 0)  # PR_SET_NAME
        except (OSError, AttributeError):
            pass
        while True:
            time.sleep(poll_s)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


GL_WAIT_POLICY = ("__GL_YIELD", "USLEEP")  # NVIDIA's driver: sleep, not spin, while waiting for the GPU
SOFTWARE_RENDER_THREADS = ("LP_NUM_THREADS", "1")  # Mesa's llvmpipe: rasterise on the worker's own thread
# What every worker (local or Ray) gets where the user has not set it: one BLAS thread (2-core machines),
# headless GL and the renderer settings above. OMP_NUM_THREADS is not here: local workers always get 1.
WORKER_ENV_DEFAULTS = (("OPENBLAS_NUM_THREADS", "1"), ("MUJOCO_GL", "egl"), GL_WAIT_POLICY,
                       SOFTWARE_RENDER_THREADS)


def limit_threads() -> None:
    """One BLAS / OpenMP / torch thread per worker process (2-core machines) and headless GL.

    On NVIDIA's EGL a process that waits for a frame spins on its core by default; with 16 workers sharing
    one GPU that spinning cost a third more CPU per expert episode (docs/results/costs.md). GL_WAIT_POLICY
    makes them sleep instead, unless the variable is already set (other drivers ignore it). Under Mesa's
    software renderer (llvmpipe, the CPU machines' EGL) SOFTWARE_RENDER_THREADS keeps each worker's
    rasteriser on its own thread rather than one per core in every worker, the set-up the 16-core scaling
    was measured in (docs/results/costs.md); likewise only where the user has not set it.

    PyTorch is not imported for this: an expert episode never needs it, and a fresh Ray worker would pay
    seconds for the import. If torch is already loaded (a forked local-pool worker inherits it) its
    thread count is set now; otherwise OMP_NUM_THREADS=1 is set, which torch reads when a job imports it
    later (e.g. to load a checkpoint)."""
    os.environ["OMP_NUM_THREADS"] = "1"
    for name, value in WORKER_ENV_DEFAULTS:
        os.environ.setdefault(name, value)
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(1)


def one_thread_unless_set() -> None:
    """One BLAS / OpenMP / torch thread for an interactive command (`bavo-demo`) unless the user chose a
    count: OMP_NUM_THREADS (and OPENBLAS_NUM_THREADS) given in the environment are kept, and torch, if it is
    loaded, then keeps its own choice too. Call it before numpy / torch load, and again once torch is
    loaded."""
    global _USER_THREADS
    if _USER_THREADS is None:
        _USER_THREADS = "OMP_NUM_THREADS" in os.environ
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    torch = sys.modules.get("torch")
    if torch is not None and not _USER_THREADS:
        torch.set_num_threads(1)


_USER_THREADS: bool | None = None  # whether OMP_NUM_THREADS was set before one_thread_unless_set first ran


RETAINED_ALLOCATION_BYTES = 1 << 30  # allocations up to 1 GiB come from (and go back to) the heap
RETAINED_FREE_BYTES = 2**31 - 1  # free heap memory kept for reuse before glibc returns any to the OS


def retain_freed_memory() -> bool:
    """Let glibc's allocator reuse freed memory for large arrays instead of unmapping it (glibc only).

    Why: an episode's per-frame arrays (240 x 320 renders, hundreds of MB per episode) are larger than
    glibc's mmap threshold (at most 32 MB when adjusted dynamically), so each one was mapped fresh and
    unmapped when freed, and every episode paid the kernel's page faults and zeroing again in its final
    `np.stack` (docs/results/costs.md). Serving such allocations from
    the heap, and keeping freed heap memory instead of trimming it, makes the next episode reuse the same
    pages. Values are unchanged (only where the memory comes from); a process keeps its peak heap size (a few
    hundred MB for a collection worker). Returns False (and changes nothing) where `mallopt` is not
    available."""
    import ctypes
    import ctypes.util

    name = ctypes.util.find_library("c")
    if not name or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError):
        return False
    M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # <malloc.h>
    return bool(mallopt(M_MMAP_THRESHOLD, RETAINED_ALLOCATION_BYTES)) and bool(
        mallopt(M_TRIM_THRESHOLD, RETAINED_FREE_BYTES))


def init_worker(parent: int | None = None, register_lerobot: bool = False) -> None:
    """Pool-worker initializer (`initializer=init_worker, initargs=(os.getpid(), register)`): `limit_threads`,
    `retain_freed_memory`, `exit_with_parent(parent)` and, with `register_lerobot`, LeRobot's env and policy
    types (`lerobot_bavo.register_lerobot_types`). Only for pool workers: in the main process the watch
    would end a run started with nohup as soon as its shell exits."""
    exit_with_parent(parent)
    limit_threads()
    retain_freed_memory()
    if register_lerobot:
        from lerobot_bavo import register_lerobot_types

        register_lerobot_types()


class LockedError(RuntimeError):
    """Another run holds the lock of this folder."""


class FolderLock:
    """A held `exclusive_lock`: `close()` (or leaving a `with` block) releases it and removes its lock file,
    so finished runs leave nothing beside their output folders."""

    def __init__(self, handle, path: Path):
        self._handle = handle
        self.path = path

    def close(self) -> None:
        """Release the lock; idempotent. The file is removed while still locked, so a run that opened it
        meanwhile finds, once it holds the lock, that the path no longer names its file and starts again
        (`exclusive_lock`): two runs never both hold one folder."""
        if self._handle is None:
            return
        with contextlib.suppress(OSError):  # a read-only parent: the stale (unlocked) file is harmless
            self.path.unlink(missing_ok=True)
        self._handle.close()
        self._handle = None

    def __enter__(self) -> FolderLock:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def exclusive_lock(folder: str | Path, tool: str) -> FolderLock:
    """An exclusive, non-blocking advisory lock for writing `folder`, keyed on its resolved real path.

    The lock file sits beside the folder (`.<name>.<tool>.lock` in its resolved parent), so every spelling
    of the same folder (symlinks, `..`) gets the same lock. Returns a `FolderLock`; closing it releases the
    lock and removes the file (the process dying releases it too, leaving the file). Raises `LockedError` if
    another process holds it."""
    import fcntl

    real = Path(folder).resolve()
    real.parent.mkdir(parents=True, exist_ok=True)
    path = real.parent / f".{real.name}.{tool}.lock"
    while True:
        handle = open(path, "a")  # noqa: SIM115  (held open while locked: FolderLock closes it)
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.close()
            raise LockedError(f"another {tool} is writing {real}") from None
        try:  # the holder before us may have removed the file after we opened it: lock the current one
            if os.stat(path).st_ino == os.fstat(handle.fileno()).st_ino:
                return FolderLock(handle, path)
        except FileNotFoundError:
            pass
        handle.close()
