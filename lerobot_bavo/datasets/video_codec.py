"""How `bavo-collect` encodes the active camera's frames: the video codec choices and their LeRobot settings.

Why a choice: LeRobot's default for RGB streams is SVT-AV1 (`libsvtav1`, GOP 2, CRF 30, preset 12,
which SVT-AV1 3.0 runs as its fastest preset M10). At BAVO's 240 x 320 it is the largest single cost of a
collection, and no SVT-AV1 setting that keeps its output (threads, asm level) makes it cheaper.
x264 at GOP 2 (the same random access for training), preset "faster", CRF 20 gives the same quality for
several times less CPU (the measurements: docs/results/costs.md), so it is the default for new datasets. The
frames handed to the encoder, their statistics and every other column are the same under both codecs.

Reproducibility (the same seeds give the same video bytes):
- x264 runs with one thread: its bitstream depends on its thread count, which would otherwise follow the
  machine's core count, and one thread is also its cheapest setting on 2 busy cores.
- On x86-64, x264 is limited to its SSE4.2 SIMD code (`x264-params: asm=SSE4.2`, `x264_simd_limit`). Its
  AVX-512 code (x264 core 165, as bundled with PyAV 15) gave a different bitstream from run to run inside
  `bavo-collect` (4 of 6 identical 1-episode collections at 240 x 320 differed; with `asm=SSE4.2` 12 of 12
  agreed, with `asm=AVX2` 6 of 6, and with `asm=0` 6 of 6 at 48 x 64), so it reads memory it does not own. Its
  SSE4.2 and AVX2 code give the same bytes and, at 240 x 320, the same CPU time, so SSE4.2 is the limit: every
  x86-64 machine since 2011 has it, and the recorded encoder options are the same on all of them. Other
  architectures use x264's own choice.
- SVT-AV1 keeps LeRobot's own settings, thread count included (its bitstream depends on neither thread count
  nor SIMD level), so `libsvtav1` writes exactly the videos earlier versions of `bavo-collect` wrote.

A dataset keeps one codec: LeRobot concatenates each episode's video into shared files, which needs equal
codecs. Datasets collected before the choice existed are `libsvtav1` (`LEGACY_VIDEO_CODEC`); the collection
record names the codec only when it is not that one, so their records still match.
"""

from __future__ import annotations

VIDEO_CODECS = ("h264", "libsvtav1")
DEFAULT_VIDEO_CODEC = "h264"  # new datasets
LEGACY_VIDEO_CODEC = "libsvtav1"  # datasets whose collection record names no codec

# LeRobot `RGBEncoderConfig` fields per codec, and the encoder thread count (LeRobot's `encoder_threads`)
_ENCODER_FIELDS = {
    "h264": {"vcodec": "h264", "pix_fmt": "yuv420p", "g": 2, "crf": 20, "preset": "faster"},
    "libsvtav1": {},  # LeRobot's defaults: libsvtav1, yuv420p, g 2, crf 30, preset 12
}
_ENCODER_THREADS = {"h264": 1, "libsvtav1": None}
# Every field of those configs as LeRobot 0.6.1 completes them (`dataclasses.asdict`; `extra_options` is
# filled in by `encoder_record`), and the codec options it derives from them (`get_codec_options(threads,
# as_strings=True)`, x264's SIMD limit added by `codec_options`): the same values without importing LeRobot,
# whose configuration package imports PyTorch (`tests/test_lerobot_format.py` compares them with LeRobot's).
_ENCODER_RECORDS = {
    "h264": {"vcodec": "h264", "pix_fmt": "yuv420p", "g": 2, "crf": 20, "preset": "faster", "fast_decode": 0,
             "video_backend": "pyav"},
    "libsvtav1": {"vcodec": "libsvtav1", "pix_fmt": "yuv420p", "g": 2, "crf": 30, "preset": 12,
                  "fast_decode": 0, "video_backend": "pyav"},
}
_CODEC_OPTIONS = {
    "h264": {"g": "2", "crf": "20", "preset": "faster", "threads": "1"},
    "libsvtav1": {"g": "2", "crf": "30", "preset": "12", "svtav1-params": "fast-decode=0"},
}


def check_video_codec(codec: str) -> str:
    """`codec` if it is one of `VIDEO_CODECS`; otherwise a ValueError naming the choices."""
    if codec not in VIDEO_CODECS:
        raise ValueError(f"unknown video codec {codec!r}; choose one of {', '.join(VIDEO_CODECS)}")
    return codec


def x264_simd_limit() -> dict[str, str]:
    """libx264 options limiting x264 to its SSE4.2 SIMD code on an x86-64 CPU that has SSE4.2 (see the module
    docstring); {} elsewhere (a name x264 does not know on another architecture would fail to open it)."""
    import platform

    if platform.machine().lower() not in ("x86_64", "amd64"):
        return {}
    try:
        from numpy._core._multiarray_umath import __cpu_features__
    except ImportError:  # pragma: no cover - numpy < 2
        from numpy.core._multiarray_umath import __cpu_features__
    return {"x264-params": "asm=SSE4.2"} if __cpu_features__.get("SSE42") else {}


def rgb_encoder(codec: str):
    """LeRobot's `RGBEncoderConfig` for `codec` (for `LeRobotDataset.create` / `resume`)."""
    from lerobot.configs.video import RGBEncoderConfig

    fields = dict(_ENCODER_FIELDS[check_video_codec(codec)])
    if codec == "h264":
        fields["extra_options"] = x264_simd_limit()
    try:  # LeRobot checks that PyAV's FFmpeg has the encoder and accepts the options
        return RGBEncoderConfig(**fields)
    except ValueError as e:
        others = ", ".join(c for c in VIDEO_CODECS if c != codec)
        raise ValueError(f"video codec {codec!r} cannot be used with this PyAV build ({e}); "
                         f"choose another with --vcodec ({others})") from None


def encoder_record(codec: str) -> dict:
    """Every field of `rgb_encoder(codec)` (`dataclasses.asdict`), which LeRobot records in a video feature's
    `info` as `video.<field>`, without importing LeRobot. A ValueError as `rgb_encoder`'s when this PyAV build
    cannot encode `codec`."""
    import av

    record = dict(_ENCODER_RECORDS[check_video_codec(codec)])
    record["extra_options"] = x264_simd_limit() if codec == "h264" else {}
    try:
        av.codec.Codec(record["vcodec"], "w")
    except Exception as e:  # av.codec.codec.UnknownCodecError
        others = ", ".join(c for c in VIDEO_CODECS if c != codec)
        raise ValueError(f"video codec {codec!r} cannot be used with this PyAV build ({e}); "
                         f"choose another with --vcodec ({others})") from None
    return record


def codec_options(codec: str) -> dict[str, str]:
    """The codec options LeRobot's encoder opens `codec` with (`rgb_encoder(codec).get_codec_options(
    encoder_threads(codec), as_strings=True)`), without importing LeRobot."""
    options = dict(_CODEC_OPTIONS[check_video_codec(codec)])
    for key, value in encoder_record(codec)["extra_options"].items():  # merged last, never overriding
        options.setdefault(key, str(value))
    return options


def encoder_threads(codec: str) -> int | None:
    """LeRobot's `encoder_threads` for `codec` (None: the codec's own choice)."""
    return _ENCODER_THREADS[check_video_codec(codec)]


def recorded_video_codec(settings: dict) -> str | None:
    """The codec of a dataset from its collection record's settings: None when it stores no video."""
    if not settings.get("use_videos", True):
        return None
    return settings.get("video_codec", LEGACY_VIDEO_CODEC)


def record_entry(codec: str, use_videos: bool) -> dict:
    """What the collection record's settings say about the codec: nothing without video or for the legacy
    codec (so records made before the choice existed still match), else {"video_codec": codec}."""
    if not use_videos or codec == LEGACY_VIDEO_CODEC:
        return {}
    return {"video_codec": check_video_codec(codec)}


def quiet_libav() -> None:
    """Silence libav's own messages below warnings (x264's statistics after every episode, the mp4 muxer's
    "moving the moov atom"): LeRobot's encoder threads hand libav back its default logger, which prints
    them."""
    import av

    av.logging.set_libav_level(av.logging.WARNING)
