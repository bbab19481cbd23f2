"""`bavo-collect` end to end: two worker processes, SIGKILL in the middle of a commit, resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lerobot_bavo.datasets import schema as S

BIN = Path(sys.executable).parent / "bavo-collect"


def _cmd(root: Path, episodes: int) -> list[str]:
    exe = [str(BIN)] if BIN.exists() else [sys.executable, "-m", "lerobot_bavo.datasets.collect"]
    return exe + [
        "--task",
        "cube_handoff",
        "--condition",
        "stage",
        "--episodes",
        str(episodes),
        "--repo-id",
        "tester/bavo_cli",
        "--root",
        str(root),
        "--workers",
        "2",
        "--commit-every",
        "2",
        "--image-height",
        "48",
        "--image-width",
        "64",
        "--n-points",
        "32",
        "--episode-length",
        "25",
        "--keep-failures",
        "--no-progress",
    ]


@pytest.mark.slow
def test_killed_collection_resumes_to_exactly_the_requested_unique_episodes(tmp_path):
    from lerobot_bavo.datasets.hub import load_bavo_dataset, read_sidecar

    root = tmp_path / "bavo_cli"
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", MUJOCO_GL="egl")
    proc = subprocess.Popen(_cmd(root, 6), env=env, start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    record_path = root / "meta" / "bavo_collection.json"
    killed_with = None
    deadline = time.time() + 400
    try:
        while proc.poll() is None and time.time() < deadline:
            try:
                rec = json.loads(record_path.read_text())
            except (FileNotFoundError, json.JSONDecodeError):
                rec = None
            if rec and rec["episodes"] and rec.get("pending_commit"):  # 2nd commit under way
                os.killpg(proc.pid, signal.SIGKILL)
                killed_with = rec
                break
            time.sleep(0.01)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    assert killed_with is not None, "the collection finished or timed out before it could be killed"

    done = subprocess.run(_cmd(root, 6), env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    rec = read_sidecar(root)
    assert [e["seed"] for e in rec["episodes"]] == list(range(6))
    assert [e["episode_index"] for e in rec["episodes"]] == list(range(6))
    ds = load_bavo_dataset("tester/bavo_cli", root=root)
    assert ds.num_episodes == 6 and len(ds) == 6 * 25
    assert [int(ds.hf_dataset[i * 25][S.ANN_SEED]) for i in range(6)] == list(range(6))
