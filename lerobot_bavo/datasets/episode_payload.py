"""The per-episode parts of a dataset write, built where the episode was recorded (a `bavo-collect` worker).

Why (issue 30): `bavo-collect`'s workers record episodes in parallel, but one process writes the dataset. When
that process also encoded each episode's video, computed its statistics and fed LeRobot frame by frame, it
spent about a third of a worker's CPU per episode (docs/results/costs.md, "Scaling with workers"), so no
worker count could make a collection more than ~4x faster than one worker. These parts depend only on the
episode, so the worker that recorded it builds them (`build_payload`) and stages them beside its columns:

- the active camera's video: an mp4 encoded frame by frame with PyAV exactly as LeRobot's streaming encoder
  thread encodes it (`video_utils.StreamingVideoEncoder`: the same codec options, pixel format, frame rate,
  frame timestamps), so the bytes are the same; the options come from the writer's `RGBEncoderConfig`
  (`video_settings`, or `codec_video_settings` where LeRobot is not loaded) and travel in the job;
- the image statistics LeRobot's encoder thread would compute while encoding: the per-frame reductions of
  every frame down-sampled as LeRobot does (`frame_reductions.py`, numpy only), finished in the copy of
  LeRobot's class that needs no PyTorch (`video_stats.stats_from_reductions`, bit for bit); the writer only
  scales them as LeRobot's writer does (`image_frame_stats` also finishes reductions staged by an earlier
  version, which left that step to the writer);
- the statistics of every numeric column, with `episode_stats.vector_stats` on the arrays LeRobot's writer
  would stack from the frames (bit for bit: the same function on the same arrays,
  `tests/test_episode_payload.py`).

The writer (`direct_writer.DirectWriterSession`, or LeRobot's through `writer.WriterSession`) then only
assigns the episode's indices, writes its parquet rows and metadata and appends the mp4 to its video file.

A worker imports neither LeRobot nor PyTorch for any of this (PyAV and numpy only): LeRobot's statistics
module imports PyTorch, ~2.8 s of CPU per worker process, so the image statistics are LeRobot's computation
split in two numpy-only parts (`frame_reductions.py`, `quantile_stats.py`).
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np

from lerobot_bavo.datasets.frame_reductions import episode_frame_reductions

# the npz members holding an episode's statistics (`stats_to_arrays`)
STATS_INDEX, STATS_DATA = "bavo_stats_index", "bavo_stats_data"


def video_settings(rgb_encoder, encoder_threads: int | None, fps: int) -> dict:
    """What a worker needs to encode exactly as LeRobot's streaming encoder with `rgb_encoder` (LeRobot's
    `RGBEncoderConfig`) and `encoder_threads` would: codec, pixel format, frames per second and the codec
    options as strings (LeRobot's own translation, `get_codec_options`). Plain data: it travels in a job."""
    return {"vcodec": rgb_encoder.vcodec, "pix_fmt": rgb_encoder.pix_fmt, "fps": int(fps),
            "options": dict(rgb_encoder.get_codec_options(encoder_threads, as_strings=True))}


def codec_video_settings(codec: str, fps: int) -> dict:
    """`video_settings(rgb_encoder(codec), encoder_threads(codec), fps)` for a codec of
    `video_codec.VIDEO_CODECS`, without importing LeRobot (`video_codec.encoder_record` / `codec_options`: the
    same values, tested)."""
    from lerobot_bavo.datasets.video_codec import codec_options, encoder_record

    record = encoder_record(codec)
    return {"vcodec": record["vcodec"], "pix_fmt": record["pix_fmt"], "fps": int(fps),
            "options": codec_options(codec)}


def encoder_options(settings: dict) -> dict[str, str]:
    """The codec options to open the encoder with on this machine: the writer's, with x264's SIMD limit of
    this machine (`video_codec.x264_simd_limit`: the writer's machine may be another architecture)."""
    from lerobot_bavo.datasets.video_codec import x264_simd_limit

    options = dict(settings["options"])
    if settings["vcodec"] == "h264":
        options.pop("x264-params", None)
        options.update(x264_simd_limit())
    return options


def encode_video(frames: np.ndarray, path: Path, settings: dict) -> None:
    """Encode (T, H, W, 3) uint8 RGB `frames` to the mp4 `path`, frame t at time t / fps (see the module
    docstring: LeRobot's streaming encoder's procedure, so the same bytes)."""
    import av

    time_base = Fraction(1, settings["fps"])
    with av.open(str(path), "w", format="mp4") as container:
        stream = container.add_stream(settings["vcodec"], settings["fps"], options=encoder_options(settings))
        stream.pix_fmt = settings["pix_fmt"]
        stream.height, stream.width = frames.shape[1], frames.shape[2]
        stream.time_base = time_base
        for t, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(rgb), format="rgb24")
            frame.pts, frame.time_base = t, time_base
            container.mux(stream.encode(frame))
        container.mux(stream.encode())


def video_frame_stats(frames: np.ndarray) -> dict[str, np.ndarray] | None:
    """The raw statistics LeRobot's streaming encoder thread reports for (T, H, W, C) uint8 frames (before the
    writer scales them to [0, 1]), None for fewer than 2 frames as LeRobot. numpy only (no LeRobot)."""
    from lerobot_bavo.datasets.video_stats import stats_from_reductions

    reductions = episode_frame_reductions(frames)
    return None if reductions is None else stats_from_reductions(reductions)


def column_stats(columns: dict[str, np.ndarray], skip: tuple[str, ...] = ()) -> dict[str, dict]:
    """`vector_stats` of every numeric (T, D) column (T >= 2) as LeRobot's writer stacks it: (T, 1) columns as
    (T,), the features of `skip` (images) left out. Columns it cannot do exactly stay with the writer."""
    from lerobot_bavo.datasets.episode_stats import vector_stats, writer_stats_inputs

    data, _ = writer_stats_inputs({k: v for k, v in columns.items() if k not in skip})
    return {k: vector_stats(v) for k, v in data.items() if v.ndim in (1, 2) and v.shape[0] >= 2
            and (np.issubdtype(v.dtype, np.number) or v.dtype == bool)}


def build_payload(columns: dict[str, np.ndarray], image_key: str, video: dict | None,
                  video_path: Path | None) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """The episode's staged columns and its statistics. With `video` (settings from `video_settings`), the
    `image_key` column is encoded to `video_path`, the raw image statistics LeRobot's streaming encoder would
    report for its frames (`video_frame_stats`, None for fewer than 2 frames) are returned under `image_key`,
    and it is left out of the columns (the writer never needs the pixels)."""
    stats = column_stats(columns, skip=(image_key,))
    if video is None:
        return columns, stats
    frames = columns[image_key]
    encode_video(frames, video_path, video)
    frame_stats = video_frame_stats(frames)
    if frame_stats is not None:
        stats[image_key] = frame_stats
    return {k: v for k, v in columns.items() if k != image_key}, stats


def image_frame_stats(staged: dict[str, np.ndarray] | None) -> dict[str, np.ndarray] | None:
    """The raw image statistics of a staged episode (what `build_payload` put under the image key): as they
    are, or finished from the frame reductions an earlier version staged instead; None when there are
    none."""
    if staged is None or "min" in staged:
        return staged
    from lerobot_bavo.datasets.frame_reductions import FrameReductions
    from lerobot_bavo.datasets.video_stats import stats_from_reductions

    return stats_from_reductions(FrameReductions.from_arrays(staged))


def stats_to_arrays(stats: dict[str, dict]) -> dict[str, np.ndarray]:
    """{feature: {statistic: array}} as two npz members: every array's bytes one after the other, and a JSON
    index (feature, statistic, dtype, shape per array, in order). Some 200 small arrays as npz members of
    their own cost the writer ~0.07 s per episode to read back (a zip entry and a header to parse each)."""
    import json

    index, chunks = [], []
    for feature, values in stats.items():
        for name, value in values.items():
            value = np.asarray(value)  # (not ascontiguousarray: it would make a 0-d array 1-d)
            index.append([feature, name, value.dtype.str, list(value.shape)])
            chunks.append(value.tobytes(order="C"))
    return {STATS_INDEX: np.frombuffer(json.dumps(index).encode(), dtype=np.uint8),
            STATS_DATA: np.frombuffer(b"".join(chunks), dtype=np.uint8)}


def stats_from_arrays(arrays: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """Split npz contents into (columns, stats): the inverse of `stats_to_arrays` (the same dtypes, shapes,
    bits and order); contents without stats give {}."""
    import json

    columns = {k: v for k, v in arrays.items() if k not in (STATS_INDEX, STATS_DATA)}
    stats: dict[str, dict] = {}
    if STATS_INDEX in arrays:
        data, offset = arrays[STATS_DATA].tobytes(), 0
        for feature, name, dtype, shape in json.loads(arrays[STATS_INDEX].tobytes()):
            dtype = np.dtype(dtype)
            count = int(np.prod(shape, dtype=np.int64))
            value = np.frombuffer(data, dtype=dtype, count=count, offset=offset).reshape(shape).copy()
            offset += count * dtype.itemsize
            stats.setdefault(feature, {})[name] = value
    return columns, stats
