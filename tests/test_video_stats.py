"""`datasets.video_stats.DeferredFrameStats` gives LeRobot 0.6.1's streaming image statistics bit for bit
(`RunningQuantileStats` fed one frame at a time, as LeRobot's video encoder thread does), and installed in
LeRobot's streaming writer it changes neither the statistics nor the video file."""

from __future__ import annotations

import contextlib
import json

import numpy as np
import pytest
from lerobot.datasets.compute_stats import RunningQuantileStats, auto_downsample_height_width

from lerobot_bavo.datasets import quantile_stats
from lerobot_bavo.datasets.video_stats import DeferredFrameStats


def encoder_rows(frame_hwc: np.ndarray) -> np.ndarray:
    """What `_CameraEncoderThread.run` hands to `stats_tracker.update` for one HWC uint8 frame."""
    chw = frame_hwc.transpose(2, 0, 1)
    small = auto_downsample_height_width(chw)
    return small.transpose(1, 2, 0).reshape(-1, small.shape[0])


def statistics(cls, batches) -> dict[str, np.ndarray]:
    tracker = cls()
    for b in batches:
        tracker.update(b)
    return tracker.get_statistics()


def assert_identical(ours: dict, theirs: dict) -> None:
    assert list(ours) == list(theirs)
    for key, expected in theirs.items():
        got = ours[key]
        assert got.dtype == expected.dtype and got.shape == expected.shape, (key, got, expected)
        assert got.tobytes() == expected.tobytes(), (key, got, expected)  # bit for bit, signed zeros included


def rendered_frames(n: int) -> list[np.ndarray]:
    """Active-camera frames of a real Stage episode at the dataset's 240 x 320 (LeRobot down-samples them)."""
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.experts import make_expert

    env = BavoEnv(task="cube_handoff", condition="stage", render_mode=None)
    try:
        obs, info = env.reset(seed=3)
        expert = make_expert(env, seed=3)
        expert.reset()
        frames = []
        for _ in range(n):
            frames.append(obs["pixels"]["active"])
            obs, *_rest, info = env.step(expert.act(obs, info))
        return frames
    finally:
        env.close()


def adversarial_batches(rng: np.random.Generator) -> dict[str, list[np.ndarray]]:
    widening = [np.clip(rng.integers(120 - 4 * i, 121 + 4 * i, size=(60, 80, 3)), 0, 255).astype(np.uint8)
                for i in range(40)]  # the range grows on most frames: histograms are re-binned mid-episode
    late = [np.full((40, 50, 3), 9, np.uint8)] * 5 + [rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)] * 3
    return {
        "random_full_range": [rng.integers(0, 256, (240, 320, 3), dtype=np.uint8) for _ in range(12)],
        "widening": widening,
        "constant": [np.full((48, 64, 3), 200, np.uint8)] * 6,  # zero-width range
        "constant_then_wide": late,  # a one-value range that widens late
        "two_frames": [rng.integers(0, 256, (48, 64, 3), dtype=np.uint8) for _ in range(2)],
        "four_channels": [rng.integers(0, 256, (30, 40, 4), dtype=np.uint8) for _ in range(7)],
        # LeRobot's own path
        "one_channel": [rng.integers(0, 256, (30, 40, 1), dtype=np.uint8) for _ in range(7)],
    }


@pytest.mark.parametrize(
    "case",
    [
        "random_full_range",
        "widening",
        "constant",
        "constant_then_wide",
        "two_frames",
        "four_channels",
        "one_channel",
    ],
)
def test_equals_lerobot_on_adversarial_frames(case):
    frames = adversarial_batches(np.random.default_rng(7))[case]
    rows = [encoder_rows(f) for f in frames]
    assert_identical(statistics(DeferredFrameStats, rows), statistics(RunningQuantileStats, rows))


@pytest.mark.parametrize("case", ["random_full_range", "widening", "constant_then_wide", "floats"])
def test_the_pytorch_free_copy_equals_lerobots_class(case):
    """`quantile_stats.RunningQuantileStats` (what the writing process of `bavo-collect` uses, without
    PyTorch) is LeRobot's class statement for statement: fed the same batches, the same statistics bit for
    bit."""
    rng = np.random.default_rng(11)
    if case == "floats":  # float batches whose range widens: re-binned histograms, interpolated quantiles
        batches = [rng.normal(i, 1.0 + i, size=(200, 5)).astype(np.float32) for i in range(8)]
        batches += [rng.normal(0.0, 3.0, size=(100, 5))]  # float64
    else:
        batches = [encoder_rows(f) for f in adversarial_batches(rng)[case]]
    assert_identical(statistics(quantile_stats.RunningQuantileStats, batches),
                     statistics(RunningQuantileStats, batches))


def test_mixed_batches_keep_lerobots_order():
    """uint8 frames, then a float batch, then frames of another size: replayed in the original order."""
    rng = np.random.default_rng(1)
    batches = ([encoder_rows(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)) for _ in range(4)]
               + [rng.normal(100.0, 40.0, size=(500, 3)).astype(np.float32)]
               + [encoder_rows(rng.integers(10, 90, (12, 16, 3), dtype=np.uint8)) for _ in range(3)]
               + [encoder_rows(rng.integers(0, 256, (24, 32, 3), dtype=np.uint8))])
    assert_identical(statistics(DeferredFrameStats, batches), statistics(RunningQuantileStats, batches))


def test_caller_may_reuse_its_frame_buffer():
    """The kept frame is a copy: overwriting the caller's array after `update` changes nothing."""
    rng = np.random.default_rng(2)
    frames = [rng.integers(0, 256, (20, 30, 3), dtype=np.uint8) for _ in range(5)]
    expected = statistics(RunningQuantileStats, [encoder_rows(f) for f in frames])
    tracker, buffer = DeferredFrameStats(), np.empty((20, 30, 3), np.uint8)
    for f in frames:
        buffer[...] = f
        tracker.update(buffer.reshape(-1, 3))
    buffer[...] = 0
    assert_identical(tracker.get_statistics(), expected)


def test_equals_lerobot_on_rendered_frames():
    rows = [encoder_rows(f) for f in rendered_frames(60)]
    assert rows[0].shape == (120 * 160, 3)  # 240 x 320 frames down-sampled by LeRobot's rule
    assert_identical(statistics(DeferredFrameStats, rows), statistics(RunningQuantileStats, rows))


def test_streaming_writer_gives_the_same_statistics_and_video(tmp_path):
    """The same frames through LeRobot's streaming writer with and without the replacement installed."""
    import lerobot.datasets.compute_stats as stats_mod
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_bavo.datasets.lerobot_private import deferred_video_frame_stats

    frames = rendered_frames(30)
    features = {"observation.images.active": {"dtype": "video", "shape": (240, 320, 3),
                                              "names": ["height", "width", "channels"]},
                "action": {"dtype": "float32", "shape": (2,), "names": None}}

    def write(root, deferred: bool):
        ds = LeRobotDataset.create("t/video_stats", 25, features, root=root, use_videos=True,
                                   streaming_encoding=True, encoder_queue_maxsize=64, video_backend="pyav")
        with deferred_video_frame_stats() if deferred else contextlib.nullcontext():
            assert (stats_mod.RunningQuantileStats is DeferredFrameStats) == deferred
            for f in frames:
                ds.add_frame({"observation.images.active": f, "action": np.zeros(2, np.float32), "task": "t"})
            ds.save_episode()
        ds.finalize()
        videos = sorted((root / "videos").rglob("*.mp4"))
        return json.loads((root / "meta" / "stats.json").read_text()), [v.read_bytes() for v in videos]

    theirs_stats, theirs_videos = write(tmp_path / "lerobot", deferred=False)
    ours_stats, ours_videos = write(tmp_path / "ours", deferred=True)
    assert stats_mod.RunningQuantileStats is RunningQuantileStats  # restored after the block
    assert ours_stats["observation.images.active"] == theirs_stats["observation.images.active"]
    assert len(ours_videos) == 1 and ours_videos == theirs_videos

