"""`bavo-collect` writes exactly the same dataset content as the reference code (issue 11).

Why: collection is restructured and sped up; what it writes must not change. The reference digests
below were made by the collector as of commit 2e08c49 (before the restructuring), on Mesa's llvmpipe
EGL renderer (rendered columns depend on the rasteriser). `BAVO_DIGEST_PRINT=1` prints the current
values, to re-pin after a deliberate, documented change of content.

What is compared, per column of `data/*.parquet`: the decoded values (images decoded from their
stored PNG bytes, so a different but lossless encoding would still compare equal), and the
per-feature statistics in `meta/stats.json` rounded to 6 significant digits (statistics computed
another way may differ in the last bits of a float).
"""

from __future__ import annotations

import hashlib
import io
import json
import os
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from _helpers import SMALL_SETTINGS

from lerobot_bavo.datasets.collect import CollectConfig, collect

SETTINGS = SMALL_SETTINGS
STEPS = 30

# Reference: 2 Cube Handoff Stage episodes (seeds 0, 1), 30 steps each, 48 x 64 images, 32 points, images in
# the parquet files (use_videos=False, so every pixel is compared exactly).
REFERENCE_COLUMNS: dict[str, str] = {
    "observation.state": "62acb175c3ddc449",
    "action": "2feff96c63911e5d",
    "observation.images.active": "f3efa31f961a483c",
    "observation.point_cloud": "8fd77bcf8b76b4fa",
    "observation.point_pixels": "94439c34af81a68c",
    "observation.camera_pose": "b7e030f8913c5b88",
    "observation.environment_state": "080eb6ba8fab8852",
    "observation.teacher.z0": "e7a268387e1d0774",
    "observation.teacher.zf": "b6de2d799ac2ae17",
    "observation.teacher.visible": "02e260f9d7553221",
    "observation.teacher.valid": "62fa39f9fa9c2148",
    "annotation.progress": "72de07267600717d",
    "annotation.occlusion_event": "72de07267600717d",
    "annotation.event_start": "91d553ce4c35f27b",
    "annotation.occlusion_active": "01579877c841e16d",
    "annotation.occlusion_target": "72de07267600717d",
    "annotation.visibility": "9a73ad44642fae69",
    "annotation.episode_seed": "89eb74c0c4f4077d",
    # Added by issue 14 (who demonstrated: 0 = expert), all zeros; every other column and statistic is
    # unchanged.
    "annotation.source": "72de07267600717d",
    "annotation.occluder_pose": "2bb6524d9c87e1da",  # added for bavo-view (issue 13)
    "timestamp": "aef64e45a1c0884e",
    "frame_index": "8651c6c887b96aea",
    "episode_index": "89eb74c0c4f4077d",
    "index": "4722b24edb2ebf3b",
    "task_index": "72de07267600717d"
}
REFERENCE_STATS = '1b58910e3774c9db'  # + annotation.occluder_pose's stats (issue 13)


def _column_digest(values: list) -> str:
    h = hashlib.sha256()
    for v in values:
        if isinstance(v, dict) and "bytes" in v:  # an image struct: hash the decoded pixels
            from PIL import Image

            arr = np.asarray(Image.open(io.BytesIO(v["bytes"])))
        else:
            arr = np.asarray(v)
        h.update(str(arr.dtype).encode() + str(arr.shape).encode())
        h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()[:16]


def dataset_digests(root: Path) -> tuple[dict[str, str], str]:
    files = sorted((root / "data").rglob("*.parquet"))
    tables = [pq.read_table(f) for f in files]
    columns = {}
    for name in tables[0].column_names:
        values = [v for t in tables for v in t.column(name).to_pylist()]
        columns[name] = _column_digest(values)
    stats = json.loads((root / "meta" / "stats.json").read_text())
    # issue 14's added column: pinned above, kept out of the reference stats
    stats.pop("annotation.source", None)

    def rounded(x):
        if isinstance(x, dict):
            return {k: rounded(v) for k, v in sorted(x.items())}
        if isinstance(x, list):
            return [rounded(v) for v in x]
        if isinstance(x, float):
            return float(f"{x:.6g}")
        return x

    stats_digest = hashlib.sha256(json.dumps(rounded(stats), sort_keys=True).encode()).hexdigest()[:16]
    return columns, stats_digest


@pytest.fixture(scope="module")
def collected(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("content") / "bavo_content"
    cfg = CollectConfig(
        task="cube_handoff",
        condition="stage",
        episodes=2,
        repo_id="tester/bavo_content",
        root=root,
        workers=0,
        commit_every=1,
        settings=SETTINGS,
        episode_length=STEPS,
        keep_failures=True,
        use_videos=False,
        progress=False,
    )
    collect(cfg)
    return root


def test_collected_content_matches_the_reference(collected):
    columns, stats = dataset_digests(collected)
    if os.environ.get("BAVO_DIGEST_PRINT"):
        print("\nREFERENCE_COLUMNS = " + json.dumps(columns, indent=4))
        print(f"REFERENCE_STATS = {stats!r}")
    assert set(columns) == set(REFERENCE_COLUMNS), "the dataset's columns changed"
    changed = sorted(k for k in columns if columns[k] != REFERENCE_COLUMNS[k])
    assert not changed, f"columns whose content changed: {changed}"
    assert stats == REFERENCE_STATS, "meta/stats.json changed"
