"""scripts/grid_runs.py: a grid's evaluation runs saved to the repository come back byte for byte, a run that
already has episodes is never overwritten, and the archive's gzip is reproducible (same log, same bytes)."""

from __future__ import annotations

import gzip
import json
from pathlib import Path

import pytest
from _helpers import load_script


@pytest.fixture(scope="module")
def grid_runs():
    return load_script("scripts/grid_runs.py")


def write_run(folder: Path, seeds: range) -> bytes:
    folder.mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"seed": 2000, "policy": "expert", "point_frame": "base"}))
    log = b"".join(
        json.dumps({"seed": s, "success": s % 2 == 0, "progress": 5, "steps": 10, "task": "cube_handoff",
                    "condition": "clean"}).encode() + b"\n" for s in seeds)
    (folder / "episodes.jsonl").write_bytes(log)
    return log


def test_save_then_restore_round_trips_and_keeps_existing_logs(grid_runs, tmp_path):
    out, archive = tmp_path / "out", tmp_path / "archive"
    log = write_run(out / "runs" / "expert" / "0", range(2000, 2003))
    (out / "runs" / "frozen" / "0").mkdir(parents=True)  # a run with no episodes yet: nothing to save
    with open(out / "runs" / "expert" / "0" / "episodes.jsonl", "ab") as f:
        f.write(b'{"seed": 2003, "succ')  # a record being written when the run is saved: left out
    assert grid_runs.save(out, archive) == 1
    packed = (archive / "runs" / "expert" / "0" / "episodes.jsonl.gz").read_bytes()
    assert grid_runs.save(out, archive) == 1
    assert (archive / "runs" / "expert" / "0" / "episodes.jsonl.gz").read_bytes() == packed  # reproducible

    fresh = tmp_path / "fresh"
    assert grid_runs.restore(fresh, archive) == 1
    assert (fresh / "runs" / "expert" / "0" / "episodes.jsonl").read_bytes() == log
    assert (fresh / "runs" / "expert" / "0" / "run.json").read_bytes() == (
        out / "runs" / "expert" / "0" / "run.json").read_bytes()

    other = tmp_path / "other"
    mine = write_run(other / "runs" / "expert" / "0", range(2000, 2001))
    assert grid_runs.restore(other, archive) == 0
    assert (other / "runs" / "expert" / "0" / "episodes.jsonl").read_bytes() == mine


def test_save_leaves_an_archived_log_with_the_same_records_untouched(grid_runs, tmp_path):
    """Archived logs packed by another compressor must not be rewritten when their records are unchanged."""
    out, archive = tmp_path / "out", tmp_path / "archive"
    log = write_run(out / "runs" / "expert" / "0", range(2000, 2003))
    packed = archive / "runs" / "expert" / "0" / "episodes.jsonl.gz"
    packed.parent.mkdir(parents=True)
    other_bytes = gzip.compress(log, compresslevel=1, mtime=123)
    assert other_bytes != grid_runs.gzip_bytes(log)
    packed.write_bytes(other_bytes)
    assert grid_runs.save(out, archive) == 1
    assert packed.read_bytes() == other_bytes  # same records: kept as they were packed

    write_run(out / "runs" / "expert" / "1", range(2000, 2001))
    stale = archive / "runs" / "expert" / "1" / "episodes.jsonl.gz"
    stale.parent.mkdir(parents=True)
    stale.write_bytes(gzip.compress(b"{}\n", mtime=0))
    grid_runs.save(out, archive)
    current = (out / "runs" / "expert" / "1" / "episodes.jsonl").read_bytes()
    assert gzip.decompress(stale.read_bytes()) == current  # different records: packed again
