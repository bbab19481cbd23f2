"""The active camera's video codec in `bavo-collect` (`datasets/video_codec.py`, issue 11).

New datasets default to x264 (same quality as LeRobot's SVT-AV1 for ~4x less CPU); `libsvtav1` writes what
earlier versions wrote; a dataset keeps one codec when it is continued, and records made before the choice
existed (no `video_codec` entry) still match. Small real collections: Cube Handoff Stage, 48 x 64 images,
30-step episodes kept with `keep_failures`, written in this process.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import av
import numpy as np
import pytest

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect import CollectConfig, CollectionError, build_parser, collect
from lerobot_bavo.datasets.hub import read_info, read_sidecar
from lerobot_bavo.datasets.video_codec import (
    DEFAULT_VIDEO_CODEC,
    LEGACY_VIDEO_CODEC,
    encoder_threads,
    record_entry,
    recorded_video_codec,
    rgb_encoder,
)

SETTINGS = S.ObservationSettings(image_height=48, image_width=64, n_points=32)
STEPS = 30


def _config(root: Path, episodes: int, **kw) -> CollectConfig:
    base = dict(
        task="cube_handoff",
        condition="stage",
        episodes=episodes,
        repo_id="tester/bavo_codec",
        root=root,
        workers=0,
        commit_every=1,
        settings=SETTINGS,
        episode_length=STEPS,
        keep_failures=True,
        progress=False,
    )
    base.update(kw)
    return CollectConfig(**base)


def _image_info(root: Path) -> dict:
    return read_info(root)["features"][S.OBS_IMAGE]["info"]


def _record_settings(root: Path) -> dict:
    return read_sidecar(root)["settings"]


def _videos(root: Path) -> list[Path]:
    return sorted((root / "videos").rglob("*.mp4"))


def _stream_codecs(root: Path) -> set[str]:
    codecs = set()
    for path in _videos(root):
        with av.open(str(path)) as c:
            codecs.add(c.streams.video[0].codec_context.codec.canonical_name)
    return codecs


# ----------------------------------------------------------------------------- settings
def test_encoder_settings_per_codec():
    h264 = rgb_encoder("h264")
    assert (h264.vcodec, h264.pix_fmt, h264.g, h264.crf, h264.preset) == ("h264", "yuv420p", 2, 20, "faster")
    assert encoder_threads("h264") == 1  # x264's bitstream depends on its thread count
    import platform

    if platform.machine() == "x86_64":  # these machines: x264's AVX-512 code is not reproducible, SSE4.2 is
        assert h264.extra_options == {"x264-params": "asm=SSE4.2"}
        assert h264.get_codec_options(encoder_threads("h264"), as_strings=True) == {
            "g": "2", "crf": "20", "preset": "faster", "threads": "1", "x264-params": "asm=SSE4.2"}
    av1 = rgb_encoder("libsvtav1")  # LeRobot's own defaults, untouched
    assert (av1.vcodec, av1.g, av1.crf, av1.preset) == ("libsvtav1", 2, 30, 12)
    assert encoder_threads("libsvtav1") is None
    assert DEFAULT_VIDEO_CODEC == "h264" and LEGACY_VIDEO_CODEC == "libsvtav1"


def test_record_entries_keep_old_records_matching():
    assert record_entry("libsvtav1", use_videos=True) == {}  # what records made before the choice hold
    assert record_entry("h264", use_videos=True) == {"video_codec": "h264"}
    assert record_entry("h264", use_videos=False) == {}
    assert recorded_video_codec({"use_videos": True}) == "libsvtav1"
    assert recorded_video_codec({"use_videos": True, "video_codec": "h264"}) == "h264"
    assert recorded_video_codec({"use_videos": False}) is None


def test_unknown_codec_is_a_clear_error(tmp_path, capsys):
    with pytest.raises(ValueError, match="unknown video codec 'vp9'; choose one of h264, libsvtav1"):
        _config(tmp_path / "ds", 1, video_codec="vp9")
    with pytest.raises(SystemExit):
        build_parser().parse_args(
            ["--task", "cube_handoff", "--episodes", "1", "--repo-id", "a/b", "--vcodec", "vp9"]
        )
    assert "invalid choice: 'vp9'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown video codec"):
        rgb_encoder("av1")


def test_a_missing_encoder_names_the_way_out(monkeypatch):
    from lerobot.configs.video import VideoEncoderConfig

    monkeypatch.setattr(VideoEncoderConfig, "detect_available_encoders", lambda self, encoders: [])
    with pytest.raises(
        ValueError, match=r"video codec 'h264' cannot be used with this PyAV build .*--vcodec \(libsvtav1\)"
    ):
        rgb_encoder("h264")


# ----------------------------------------------------------------------------- collections
def test_new_dataset_is_h264_and_keeps_it_when_continued(tmp_path):
    root = tmp_path / "h264"
    collect(_config(root, 1))
    assert _image_info(root)["video.codec"] == "h264" and _image_info(root)["video.crf"] == 20
    assert _record_settings(root)["video_codec"] == "h264"
    assert "| video, H.264 (x264) |" in (root / "README.md").read_text()  # the dataset card says so
    collect(_config(root, 2))  # continued without naming a codec: stays h264
    assert _stream_codecs(root) == {"h264"}
    with pytest.raises(CollectionError, match=r"video_codec: dataset 'h264' vs now 'libsvtav1'"):
        collect(_config(root, 3, video_codec="libsvtav1"))


def test_libsvtav1_dataset_looks_like_an_old_one_and_stays_av1(tmp_path):
    root = tmp_path / "av1"
    collect(_config(root, 1, video_codec="libsvtav1"))
    # exactly the settings of records made before the choice
    assert "video_codec" not in _record_settings(root)
    assert _image_info(root)["video.codec"] == "av1" and _image_info(root)["video.crf"] == 30
    assert "| video, AV1 (SVT-AV1) |" in (root / "README.md").read_text()
    collect(_config(root, 2))  # the default would be h264 for a new dataset; this one keeps AV1
    assert _stream_codecs(root) == {"av1"}
    assert "video_codec" not in _record_settings(root)
    with pytest.raises(CollectionError, match=r"video_codec: dataset 'libsvtav1' vs now 'h264'"):
        collect(_config(root, 3, video_codec="h264"))


def test_h264_video_is_reproducible_and_faithful(tmp_path):
    """Same seeds, same video bytes (one x264 thread, no AVX-512 code); frames decode close to the renders.
    At the full 240 x 320, without the SIMD limit, 4 of 6 such runs differed on these machines (AVX-512)."""
    full = S.ObservationSettings(image_height=240, image_width=320, n_points=32)
    digests = []
    for name in ("a", "b", "c", "d"):
        root = tmp_path / name
        collect(_config(root, 1, settings=full))
        (video,) = _videos(root)
        digests.append(hashlib.sha256(video.read_bytes()).hexdigest())
    assert len(set(digests)) == 1, digests

    from lerobot_bavo.datasets.recording import EpisodeRecorder

    rec = EpisodeRecorder("cube_handoff", "stage", full, episode_length=STEPS)
    try:
        rgb = rec.record(seed=0).rgb
    finally:
        rec.close()
    with av.open(str(video)) as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(frames) == STEPS
    err = np.abs(np.stack(frames).astype(np.float64) - rgb.astype(np.float64))
    assert err.mean() < 6.0, err.mean()
