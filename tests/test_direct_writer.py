"""`direct_writer.DirectWriterSession` writes the files LeRobot 0.6.1's writer makes (issue 30).

The same staged episodes (synthetic columns with the BAVO schema, each with its worker-encoded mp4 and worker
statistics, as `staging.stage_episode` stages them) go through LeRobot's writer (`writer.WriterSession`, what
`bavo-collect` used before) into one dataset and through `DirectWriterSession` into another, in the same
writer sessions: a new dataset, sessions that resume it, a session of more than ten episodes (LeRobot writes
episode rows ten at a time and then, by its own size estimate, starts a new episode-table file), and with tiny
file-size limits that make both writers start new data and video files inside a session. Every file must be
the same bytes (`meta/stats.json` the same values: LeRobot's key order varies from run to run), but for the
data files written with the page encoding `bavo-collect` uses, which must hold the same tables.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from _helpers import SMALL_SETTINGS

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect_config import CollectConfig, CollectionError
from lerobot_bavo.datasets.collection_record import write_json_atomic
from lerobot_bavo.datasets.direct_writer import DirectWriterSession
from lerobot_bavo.datasets.episode_payload import build_payload, codec_video_settings, stats_to_arrays
from lerobot_bavo.datasets.session import DatasetSession
from lerobot_bavo.datasets.staging import staged_path
from lerobot_bavo.datasets.writer import WriterSession

SETTINGS = SMALL_SETTINGS


def _config(root: Path, codec: str = "h264") -> CollectConfig:
    return CollectConfig(task="cube_handoff", condition="stage", episodes=100, repo_id="tester/direct",
                         root=root, workers=0, settings=SETTINGS, video_codec=codec, progress=False)


def _columns(features: dict, seed: int) -> dict[str, np.ndarray]:
    """Random frame-leading columns for every stored feature of `features` (as `recording.episode_frames`
    gives them: (T, 1) for scalars), and moving-gradient frames with some noise for the camera."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(150, 260))
    cols = {}
    for key, ft in features.items():
        if key in ("timestamp", "frame_index", "episode_index", "index", "task_index"):
            continue
        if ft["dtype"] == "video":
            h, w, _ = ft["shape"]
            ramp = (np.arange(w)[None, None, :] + 3 * np.arange(n)[:, None, None]) % 256
            frames = np.broadcast_to(ramp[..., None], (n, h, w, 3)).astype(np.int16)
            frames = frames + rng.integers(-80, 81, size=frames.shape)
            cols[key] = np.clip(frames, 0, 255).astype(np.uint8)
        elif ft["dtype"] == "int64":
            cols[key] = rng.integers(0, 5, size=(n, ft["shape"][0])).astype(np.int64)
        else:
            cols[key] = rng.normal(0.0, 1.0 + seed % 3, size=(n, ft["shape"][0])).astype(ft["dtype"])
    return cols


def _stage(session: DatasetSession, seed: int, features: dict) -> dict:
    """Stage a synthetic episode in `session`'s staging folder exactly as a worker does (mp4, npz, marker)."""
    cols = _columns(features, seed)
    staging = session.staging
    staging.mkdir(parents=True, exist_ok=True)
    video = codec_video_settings(session.video_codec, S.FPS)
    cols, stats = build_payload(cols, S.OBS_IMAGE, video, staged_path(staging, seed, ".mp4"))
    with open(staged_path(staging, seed, ".npz"), "wb") as f:
        np.savez(f, **{k.replace(".", "__"): v for k, v in {**cols, **stats_to_arrays(stats)}.items()})
    summary = {"seed": seed, "success": True, "kept": True, "length": int(cols[S.ACTION].shape[0]),
               "progress": 5, "recoveries": 0, "video": True}
    write_json_atomic(staged_path(staging, seed, ".json"), summary)
    return summary


def _write(root: Path, sessions: list[list[int]], direct: bool, sizes: dict | None, codec: str,
           lerobot_encoding: bool = True) -> None:
    session = DatasetSession(_config(root, codec))
    lock = session.lock()
    try:
        session.open()
        if sizes:
            info_path = root / "meta" / "info.json"
            info = json.loads(info_path.read_text())
            info.update(sizes)
            info_path.write_text(json.dumps(info, indent=4))
        features = json.loads((root / "meta" / "info.json").read_text())["features"]
        for seeds in sessions:
            summaries = [_stage(session, seed, features) for seed in seeds]
            writer = DirectWriterSession(session, lerobot_encoding=lerobot_encoding) if direct else \
                WriterSession(session, max(s["length"] for s in summaries))
            for summary in summaries:
                writer.add(summary)
            writer.close()
    finally:
        lock.close()


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and ".bavo_staging" not in p.parts}


TINY = {"data_files_size_in_mb": 1, "video_files_size_in_mb": 1}


@pytest.mark.parametrize("codec,sizes,lerobot_encoding",
                         [# LeRobot's default file sizes, byte for byte: ~28 s on 2 cores and checked
                          # by default with smaller files (which also roll over), so with `-m slow`
                          pytest.param("h264", None, True, marks=pytest.mark.slow), ("h264", TINY, True),
                          # the optional AV1 codec: ~30 s on 2 cores, so with `-m slow`
                          pytest.param("libsvtav1", None, True, marks=pytest.mark.slow),
                          ("h264", None, False)],
                         ids=["default-file-sizes", "tiny-file-sizes", "libsvtav1", "collection-encoding"])
def test_the_same_files_as_lerobots_writer(tmp_path, codec, sizes, lerobot_encoding):
    """With `lerobot_encoding` every file is LeRobot's bytes; with the encoding `bavo-collect` uses (list
    columns not dictionary-encoded) the data files hold the same tables and every other file is the same."""
    import pyarrow.parquet as pq

    sessions = [[0, 1, 2], [3], [4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15]]
    _write(tmp_path / "lerobot", sessions, direct=False, sizes=sizes, codec=codec)
    _write(tmp_path / "direct", sessions, direct=True, sizes=sizes, codec=codec,
           lerobot_encoding=lerobot_encoding)
    theirs, ours = _files(tmp_path / "lerobot"), _files(tmp_path / "direct")
    assert sorted(ours) == sorted(theirs)
    if sizes:  # the tiny limits made both writers start new files inside sessions (episode rows: at the 11th)
        for folder in ("data/", "videos/", "meta/episodes/"):
            assert len([k for k in ours if k.startswith(folder)]) > len(sessions), folder
    for name in theirs:
        if name == "meta/stats.json":
            assert json.loads(ours[name]) == json.loads(theirs[name])
        elif name == "meta/bavo_collection.json":
            assert json.loads(ours[name])["episodes"] == json.loads(theirs[name])["episodes"]
        elif name.startswith("data/") and not lerobot_encoding:
            assert ours[name] != theirs[name] and len(ours[name]) < len(theirs[name])
            table = pq.read_table(tmp_path / "direct" / name)
            assert table.equals(pq.read_table(tmp_path / "lerobot" / name), check_metadata=True), name
        else:
            assert ours[name] == theirs[name], name


def test_refuses_what_it_cannot_write_as_lerobot_would(tmp_path):
    """An episode staged without its mp4, or with a column of another dtype, is refused and rolled back."""
    root = tmp_path / "ds"
    session = DatasetSession(_config(root))
    lock = session.lock()
    try:
        session.open()
        features = json.loads((root / "meta" / "info.json").read_text())["features"]
        summary = _stage(session, 0, features)
        os.remove(staged_path(session.staging, 0, ".mp4"))
        writer = DirectWriterSession(session)
        with pytest.raises(CollectionError, match="no video"):
            writer.add(summary)
        writer.abort()
        summary = _stage(session, 1, features)
        with np.load(staged_path(session.staging, 1, ".npz")) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["action"] = arrays["action"].astype(np.float64)
        with open(staged_path(session.staging, 1, ".npz"), "wb") as f:
            np.savez(f, **arrays)
        writer = DirectWriterSession(session)
        with pytest.raises(CollectionError, match="does not match the dataset's features"):
            writer.add(summary)
        writer.abort()
        assert json.loads((root / "meta" / "info.json").read_text())["total_episodes"] == 0
        assert not (root / "data").exists() and not (root / "videos").exists()
    finally:
        lock.close()
