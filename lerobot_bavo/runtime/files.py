"""Writing result and record files so that a failure never leaves a half-written one, or a set that disagrees.

Why: `bavo-eval` wrote results.json in place, then results.md: a full disk left invalid JSON (a later reader
fails on it) and the previous run's results.md beside it. Now every file of a set is written to `<name>.tmp`
in its own folder and flushed to disk first; only then are they renamed into place (`os.replace`, atomic
within a file system, and needing no space). A failed write removes the temporaries and leaves every target as
it was.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from pathlib import Path


def default_file_mode() -> int:
    """The mode `open()` gives a new file here: 0o666 less the process umask (read without changing it where
    the OS reports it; else by setting it and back, which is not thread-safe: call it while no other thread
    creates files)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return 0o666 & ~int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


def _fsync_folder(folder: Path) -> None:
    """Make the renames in `folder` durable (where the OS allows opening a folder)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_files_atomic(files: Mapping[str | Path, str | bytes]) -> None:
    """Write every `path -> content` (text is UTF-8) through `<path>.tmp` (flushed and fsynced), then rename
    them all into place. An OSError while writing (ENOSPC, EFBIG, EIO) removes the temporaries, leaves every
    target unchanged, and propagates. New files get the usual mode (umask), as `Path.write_text` gives
    them."""
    temps: list[tuple[Path, Path]] = []
    try:
        for path, content in files.items():
            path = Path(path)
            tmp = path.with_name(path.name + ".tmp")
            temps.append((tmp, path))
            data = content.encode() if isinstance(content, str) else content
            with open(tmp, "wb") as fh:
                fh.write(data)
                fh.flush()
                os.fsync(fh.fileno())
    except BaseException:
        for tmp, _ in temps:
            tmp.unlink(missing_ok=True)
        raise
    for tmp, path in temps:
        os.replace(tmp, path)
    for folder in {path.parent for _, path in temps}:
        _fsync_folder(folder)


def write_file_atomic(path: str | Path, content: str | bytes) -> None:
    """`write_files_atomic` for one file."""
    write_files_atomic({path: content})


def restore_default_mode(paths: Iterable[str | Path]) -> list[Path]:
    """Give every file of `paths` that is private (mode 0600) the mode new files get here
    (`default_file_mode`); returns those changed. Why: LeRobot builds a video file that grows past one episode
    in a `NamedTemporaryFile` (mode 0600) and moves it into the dataset, so those mp4s were unreadable to
    other users while every other file of the dataset was 0644."""
    mode = default_file_mode()
    changed = []
    for path in map(Path, paths):
        if path.is_file() and path.stat().st_mode & 0o777 == 0o600 and mode != 0o600:
            path.chmod(mode)
            changed.append(path)
    return changed
