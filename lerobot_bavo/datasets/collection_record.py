"""The collection record (`meta/bavo_collection.json`): what `bavo-collect` has committed to a dataset.

Why a record beside LeRobot's metadata: LeRobot's `meta/` says how many episodes a dataset holds, not
which seeds they came from, which attempts were discarded, where the next run must continue, or
whether a writer session was interrupted half-way. The record is the collector's source of truth for
resume; `meta/info.json` must agree with it (episode count) or the dataset was edited elsewhere.

On disk it is plain JSON (other modules, e.g. the dataset card and the teacher cache, read it as a
dict through `hub.read_sidecar`); in the collector it is this dataclass.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

from lerobot_bavo.datasets.metadata import SIDECAR
from lerobot_bavo.runtime.files import write_file_atomic

RECORD_FORMAT = 1


def write_json_atomic(path: Path, obj) -> None:
    """Write JSON through a temporary file and a rename, so a kill or a full disk never leaves half a file."""
    write_file_atomic(path, json.dumps(obj, indent=1))


@dataclass
class PendingCommit:
    """A writer session that started and has not been confirmed: roll it back on the next start."""

    seeds: list[int]
    next_seed: int


@dataclass
class CollectionRecord:
    """The state of one dataset's collection.

    Args:
        repo_id: the dataset's `<user>/<name>`.
        settings: what must match for a run to continue the dataset (`CollectConfig.record_settings()`).
        episodes: committed episodes, in dataset order: {"episode_index", "seed", "length", "recoveries"}.
        discarded: unsuccessful attempts: {"seed", "progress", "length"}.
        next_seed: the first seed not yet resolved (kept or discarded).
        pending_commit: the writer session in progress, or None.
        runs: one summary per `bavo-collect` run (timings, attempts, per-commit times).
        complete: all requested episodes are committed and the finishing steps ran.
        extra: other keys found on disk (e.g. `command`, `point_cloud_channel_stats`), kept as they are.
    """

    repo_id: str
    settings: dict
    episodes: list[dict] = field(default_factory=list)
    discarded: list[dict] = field(default_factory=list)
    next_seed: int = 0
    pending_commit: PendingCommit | None = None
    runs: list[dict] = field(default_factory=list)
    complete: bool = False
    extra: dict = field(default_factory=dict)

    @classmethod
    def from_dict(cls, d: dict) -> CollectionRecord:
        known = {f.name for f in dataclasses.fields(cls)} - {"extra"}
        pending = d.get("pending_commit")
        return cls(
            repo_id=d.get("repo_id", ""),
            settings=d["settings"],
            episodes=list(d.get("episodes", [])),
            discarded=list(d.get("discarded", [])),
            next_seed=int(d.get("next_seed", 0)),
            pending_commit=PendingCommit(list(pending["seeds"]), int(pending["next_seed"]))
            if pending
            else None,
            runs=list(d.get("runs", [])),
            complete=bool(d.get("complete", False)),
            extra={k: v for k, v in d.items() if k not in known and k != "format"},
        )

    def to_dict(self) -> dict:
        out = {"format": RECORD_FORMAT, "repo_id": self.repo_id, "settings": self.settings,
               "episodes": self.episodes, "discarded": self.discarded, "next_seed": self.next_seed,
               "pending_commit": dataclasses.asdict(self.pending_commit) if self.pending_commit else None,
               "runs": self.runs, "complete": self.complete}
        out.update(self.extra)
        return out

    @classmethod
    def load(cls, root: Path) -> CollectionRecord | None:
        """The record of the dataset at `root`, None if it has none; a malformed one raises naming the
        file."""
        from lerobot_bavo.datasets.metadata import read_sidecar

        d = read_sidecar(root)
        return None if d is None else cls.from_dict(d)

    def save(self, root: Path) -> None:
        write_json_atomic(Path(root) / SIDECAR, self.to_dict())

    @property
    def frames(self) -> int:
        return sum(e["length"] for e in self.episodes)
