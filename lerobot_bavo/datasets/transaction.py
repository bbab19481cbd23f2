"""Commit and roll back one LeRobot writer session on a dataset folder (how `bavo-collect` resumes).

Why: LeRobot keeps its parquet writers open until `finalize()`, so a process killed inside a writer
session leaves unreadable files. A resumed LeRobot writer only ever *adds* files under `data/`,
`videos/` and `meta/episodes/` and rewrites three metadata files. So before a session the collector
takes a snapshot (the three metadata files and the list of managed files); if the session does not
finish, rolling back deletes the files not in the list and restores the metadata. Nothing here knows
about episodes or seeds: the collection record says which session is pending.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

from lerobot_bavo.datasets.collection_record import write_json_atomic

MANAGED_DIRS = ("data", "videos", os.path.join("meta", "episodes"))
SNAPSHOT_FILES = (os.path.join("meta", "info.json"), os.path.join("meta", "stats.json"),
                  os.path.join("meta", "tasks.parquet"))
LISTING = "files.json"


class SnapshotMissing(RuntimeError):
    """A pending session cannot be rolled back: its snapshot is gone."""


class WriterSessionSnapshot:
    """The snapshot of a dataset folder `root`, kept in `snapshot_dir` (inside the staging folder)."""

    def __init__(self, root: Path, snapshot_dir: Path):
        self.root = Path(root)
        self.dir = Path(snapshot_dir)

    def managed_files(self) -> list[str]:
        """Files a writer session may add, relative to `root`, sorted."""
        out = []
        for d in MANAGED_DIRS:
            base = self.root / d
            if base.exists():
                out += [str(p.relative_to(self.root)) for p in base.rglob("*") if p.is_file()]
        return sorted(out)

    def take(self) -> None:
        """Record the state before a writer session."""
        shutil.rmtree(self.dir, ignore_errors=True)
        self.dir.mkdir(parents=True)
        present = []
        for rel in SNAPSHOT_FILES:
            src = self.root / rel
            if src.exists():
                shutil.copy2(src, self.dir / Path(rel).name)
                present.append(rel)
        write_json_atomic(self.dir / LISTING, {"files": self.managed_files(), "meta": present})

    def restore(self) -> None:
        """Undo everything a writer session did since `take()`; then drop the snapshot."""
        if not (self.dir / LISTING).exists():
            raise SnapshotMissing(f"its snapshot ({self.dir}) is gone")
        listing = json.loads((self.dir / LISTING).read_text())
        keep = set(listing["files"])
        for rel in self.managed_files():
            if rel not in keep:
                (self.root / rel).unlink()
        for rel in SNAPSHOT_FILES:
            dst = self.root / rel
            if rel in listing["meta"]:
                shutil.copy2(self.dir / Path(rel).name, dst)
            elif dst.exists():
                dst.unlink()
        for d in MANAGED_DIRS:  # drop directories left empty
            base = self.root / d
            if base.exists():
                for p in sorted(base.rglob("*"), key=lambda p: len(p.parts), reverse=True):
                    if p.is_dir() and not any(p.iterdir()):
                        p.rmdir()
        self.discard()

    def discard(self) -> None:
        """The session finished (or none was pending): the snapshot is no longer needed."""
        shutil.rmtree(self.dir, ignore_errors=True)


def remove_stray_dirs(root: Path, keep: tuple[str, ...]) -> None:
    """Delete LeRobot's temporary encoder / image folders that a killed writer left in `root`."""
    for p in Path(root).iterdir():
        if p.is_dir() and p.name not in ("data", "videos", "meta", *keep):
            shutil.rmtree(p, ignore_errors=True)
