"""Per-episode dataset parts built by the worker that recorded the episode (issue 30).

`bavo-collect`'s workers now encode the active camera's mp4 and compute the statistics the writing process
used to compute (`datasets/episode_payload.py`), and the writer hands LeRobot one prepared buffer per
episode. What must hold: the worker's mp4 is the bytes LeRobot's streaming encoder writes for the same
frames, its statistics are LeRobot's bit for bit, a whole collection is byte-identical to one whose writer
encodes and computes as before (the frame-by-frame path, still used without video and by `bavo-teleop`),
the writer encodes nothing itself, and a staged episode whose mp4 is missing is redone on resume.
`bavo-eval`'s side: results come back in completion order, and an expert run imports no PyTorch.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect import CollectConfig, Collector, collect
from lerobot_bavo.datasets.episode_payload import (
    build_payload,
    encode_video,
    image_frame_stats,
    stats_from_arrays,
    stats_to_arrays,
    video_frame_stats,
    video_settings,
)
from lerobot_bavo.datasets.frame_reductions import FrameReductions, downsample, episode_frame_reductions
from lerobot_bavo.datasets.video_codec import encoder_threads, rgb_encoder
from lerobot_bavo.datasets.video_stats import stats_from_reductions
from lerobot_bavo.runtime.pool import WorkerPool

REPO = Path(__file__).resolve().parents[1]


def _frames(n: int = 12, height: int = 240, width: int = 320) -> np.ndarray:
    """Smooth moving gradients plus noise: something an encoder has to work on, the same every run."""
    rng = np.random.default_rng(0)
    y, x = np.mgrid[0:height, 0:width]
    frames = np.empty((n, height, width, 3), dtype=np.uint8)
    for t in range(n):
        base = np.stack([(x + 3 * t) % 256, (y + 5 * t) % 256, (x + y + 7 * t) % 256], axis=-1)
        frames[t] = np.clip(base + rng.integers(-8, 9, size=base.shape), 0, 255)
    return frames


@pytest.mark.parametrize("codec", ["h264", "libsvtav1"])
def test_worker_video_and_its_statistics_are_what_lerobots_streaming_encoder_writes(codec, tmp_path):
    """The same frames through LeRobot's `StreamingVideoEncoder` (its own statistics class, no
    replacement) and through `episode_payload` (the worker's frame reductions and statistics): the same mp4
    bytes and the same raw statistics, bit for bit (at 240 x 320, where LeRobot down-samples frames for
    statistics), and they survive staging, as do the reductions an earlier version staged."""
    from lerobot.datasets.video_utils import StreamingVideoEncoder

    frames = _frames()
    encoder = StreamingVideoEncoder(S.FPS, rgb_encoder=rgb_encoder(codec), queue_maxsize=len(frames) + 4,
                                    encoder_threads=encoder_threads(codec))
    encoder.start_episode(video_keys=[S.OBS_IMAGE], temp_dir=tmp_path)
    for frame in frames:
        encoder.feed_frame(S.OBS_IMAGE, frame)
    lerobot_path, lerobot_stats = encoder.finish_episode()[S.OBS_IMAGE]
    ours = tmp_path / "worker.mp4"
    encode_video(frames, ours, video_settings(rgb_encoder(codec), encoder_threads(codec), S.FPS))
    assert ours.read_bytes() == Path(lerobot_path).read_bytes()
    stats = video_frame_stats(frames)
    # what a worker stages (the finished statistics), and what an earlier version staged (the reductions)
    _, staged = stats_from_arrays(stats_to_arrays({"f": stats,
                                                   "r": episode_frame_reductions(frames).to_arrays()}))
    restaged = stats_from_reductions(FrameReductions.from_arrays(staged["r"]))
    for got in (stats, restaged, image_frame_stats(staged["f"]), image_frame_stats(staged["r"])):
        assert list(got) == list(lerobot_stats)
        for key, value in lerobot_stats.items():
            assert got[key].dtype == value.dtype and got[key].shape == value.shape, key
            assert np.array_equal(got[key], value), key


def test_a_worker_builds_the_payload_without_lerobot_or_pytorch(tmp_path):
    """The worker side (encoding, frame reductions, column statistics) needs PyAV and numpy only: a spawned
    collection worker stays light (`WorkerPool(light_import=True)`), ~2.8 s of CPU less per worker."""
    code = (
        "import sys\n"
        "import numpy as np\n"
        "from lerobot_bavo.datasets.episode_payload import build_payload\n"
        "frames = np.random.default_rng(0).integers(0, 255, (4, 48, 64, 3), dtype=np.uint8)\n"
        "video = {'vcodec': 'h264', 'pix_fmt': 'yuv420p', 'fps': 25,\n"
        "         'options': {'g': '2', 'crf': '20', 'preset': 'faster', 'threads': '1'}}\n"
        "cols = {'observation.images.active': frames, 'action': np.zeros((4, 3), np.float32)}\n"
        f"path = {str(tmp_path / 'v.mp4')!r}\n"
        "staged, stats = build_payload(cols, 'observation.images.active', video, path)\n"
        "assert sorted(stats) == ['action', 'observation.images.active'] and list(staged) == ['action']\n"
        "print('IMPORTED', 'torch' in sys.modules, 'lerobot' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "IMPORTED False False" in out.stdout and (tmp_path / "v.mp4").stat().st_size > 0


def test_worker_column_statistics_are_lerobots_and_survive_staging():
    """`build_payload`'s statistics equal LeRobot's `compute_episode_stats` of the arrays its writer stacks
    (bit for bit, dtypes included), and the npz round trip keeps them; the image column is left out."""
    from lerobot.datasets.compute_stats import compute_episode_stats

    from lerobot_bavo.datasets.episode_stats import writer_stats_inputs

    rng = np.random.default_rng(1)
    T = 40
    columns = {S.OBS_STATE: rng.normal(size=(T, 21)).astype(np.float32),
               S.OBS_POINT_CLOUD: rng.normal(size=(T, 32 * 6)).astype(np.float32),
               S.ANN_PROGRESS: rng.integers(0, 5, size=(T, 1)).astype(np.int64),
               S.ANN_VISIBILITY: rng.random(size=(T, 1)).astype(np.float32),
               S.OBS_IMAGE: np.zeros((T, 8, 8, 3), dtype=np.uint8)}
    staged, stats = build_payload(columns, S.OBS_IMAGE, video=None, video_path=None)
    assert staged is columns and S.OBS_IMAGE not in stats
    data, features = writer_stats_inputs({k: v for k, v in columns.items() if k != S.OBS_IMAGE})
    reference = compute_episode_stats(data, features)
    assert list(stats) == list(reference)
    _, back = stats_from_arrays(stats_to_arrays({**stats, "scalar": {"n": np.asarray(7)}}))
    assert back["scalar"]["n"].shape == () and int(back["scalar"]["n"]) == 7
    for key, ref in reference.items():
        for name, value in ref.items():
            for got in (stats[key][name], back[key][name]):
                assert got.dtype == value.dtype and np.array_equal(got, value), (key, name)


def test_downsampling_is_lerobots():
    from lerobot.datasets.compute_stats import auto_downsample_height_width

    for height, width in ((48, 64), (240, 320), (299, 200), (300, 200), (480, 640), (720, 1280), (640, 480)):
        chw = np.zeros((3, height, width), dtype=np.uint8)
        assert downsample(chw).shape == auto_downsample_height_width(chw).shape


def _config(root: Path, **kw) -> CollectConfig:
    return CollectConfig(task="cube_handoff", condition="stage", episodes=2, repo_id="tester/bavo_payload",
                         root=root, workers=0, commit_every=1,
                         settings=S.ObservationSettings(image_height=48, image_width=64, n_points=32),
                         episode_length=30, keep_failures=True, use_videos=True, progress=False, **kw)


def _files(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in root.rglob("*")
            if p.is_file() and p.name not in ("bavo_collection.json", "README.md", "stats.json")}


def test_a_collection_with_worker_payloads_is_byte_identical_to_the_writer_encoding_itself(tmp_path,
                                                                                             monkeypatch):
    """Two video collections of the same seeds: one as `bavo-collect` runs now (the worker encodes, the
    direct writer writes the files, LeRobot's encoder is made to fail if it is ever asked to), one whose
    workers get no encoder settings, so LeRobot's writer is fed frame by frame as before issue 30. Every
    video and metadata file is the same bytes, stats.json the same statistics, the data files the same
    tables."""
    import lerobot.datasets.video_utils as video_utils

    def refuse(*args, **kwargs):
        raise AssertionError("the writing process encoded video")

    with monkeypatch.context() as m:
        m.setattr(video_utils.StreamingVideoEncoder, "start_episode", refuse)
        m.setattr(video_utils.StreamingVideoEncoder, "feed_frame", refuse)
        m.setattr(video_utils, "encode_video_frames", refuse)
        collect(_config(tmp_path / "worker"))
    with monkeypatch.context() as m:
        m.setattr(Collector, "_video", None)
        collect(_config(tmp_path / "writer"))
    worker, writer = _files(tmp_path / "worker"), _files(tmp_path / "writer")
    assert any(k.endswith(".mp4") for k in worker)
    assert sorted(worker) == sorted(writer)
    data = [k for k in worker if k.startswith("data/")]
    assert data and {k: v for k, v in worker.items() if k not in data} == \
        {k: v for k, v in writer.items() if k not in data}
    for name in data:  # the direct writer encodes pages its own way (direct_writer.py, "Data pages")
        tables = [pq.read_table(tmp_path / d / name) for d in ("worker", "writer")]
        assert tables[0].equals(tables[1], check_metadata=True), name
    stats = [json.loads((tmp_path / d / "meta" / "stats.json").read_text()) for d in ("worker", "writer")]
    assert stats[0] == stats[1]


def test_a_staged_episode_whose_video_is_missing_is_redone(tmp_path):
    """Resume: a completion marker that names a worker-encoded video counts only with that mp4 and the npz
    beside it; otherwise the episode is dropped (and recorded again), as a marker without its columns is."""
    from lerobot_bavo.datasets.session import DatasetSession
    from lerobot_bavo.datasets.staging import staged_path

    session = DatasetSession(_config(tmp_path / "ds"))
    session.staging.mkdir(parents=True)
    for seed, files in ((0, (".npz", ".mp4")), (1, (".npz",)), (2, (".mp4",))):
        for suffix in files:
            staged_path(session.staging, seed, suffix).write_bytes(b"x")
        staged_path(session.staging, seed, ".json").write_text(json.dumps(
            {"seed": seed, "kept": True, "video": True, "length": 30}))
    assert sorted(session.scan_staging(0)) == [0]
    assert sorted(p.name for p in session.staging.iterdir()) == [
        "seed_00000000.json", "seed_00000000.mp4", "seed_00000000.npz"]


def _sleep_job(job: dict) -> int:
    time.sleep(job["sleep"])
    if job.get("fail"):
        raise ValueError("bad job")
    return job["i"]


def test_unordered_results_come_as_jobs_finish_and_errors_propagate():
    with WorkerPool(2, light_import=True) as pool:
        jobs = [{"i": 0, "sleep": 1.5}, {"i": 1, "sleep": 0.0}, {"i": 2, "sleep": 0.0}]
        results = list(pool.imap_unordered(_sleep_job, jobs))
        assert sorted(results) == [0, 1, 2] and results[-1] == 0  # the slow one did not hold the others
        with pytest.raises(ValueError, match="bad job"):
            list(pool.imap_unordered(_sleep_job, [{"i": 0, "sleep": 0.0, "fail": True}]))
    assert list(WorkerPool(0).imap_unordered(_sleep_job, [{"i": 5, "sleep": 0.0}])) == [5]


def test_an_expert_evaluation_imports_no_pytorch(tmp_path):
    """`bavo-eval --policy expert` needs neither LeRobot nor PyTorch in the coordinating process (they were
    its largest serial cost); the episode job is replaced by a stub so that only the coordinator runs."""
    code = (
        "import sys\n"
        "import lerobot_bavo.eval.run as run\n"
        "run.run_job = lambda job: {'task': job['task'], 'condition': job['condition'],\n"
        "                           'seed': job['seed'], 'success': True, 'progress': 5}\n"
        "from lerobot_bavo.eval.cli import main\n"
        "main(['--policy', 'expert', '--tasks', 'cube_handoff', '--conditions', 'stage', '--episodes', '2',\n"
        f"      '--workers', '1', '--videos', '0', '--output-dir', {str(tmp_path / 'out')!r}])\n"
        "print('TORCH', 'torch' in sys.modules, 'lerobot' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "TORCH False False" in out.stdout
