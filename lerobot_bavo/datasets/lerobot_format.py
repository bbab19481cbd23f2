"""LeRobot 0.6.1's v3.0 dataset files as its writer makes them, without importing LeRobot (or PyTorch).

Why (issue 30): every module of LeRobot's dataset package imports PyTorch, and its configuration package
torchvision and `torch._dynamo` with it: ~2.9 s of CPU before the first episode, in the one process that
writes a `bavo-collect` dataset while the workers record. That process's share of all CPU is the serial part
of a collection (Amdahl), so it writes the files itself (`direct_writer.py`), with the pieces here: LeRobot's
own procedures for the files an append session touches, copied statement for statement where the bytes
depend on it, with numpy, pyarrow, PyAV and json only.

What each piece follows (LeRobot 0.6.1, `lerobot/datasets/`):
- `new_info`, `normalized_info`, `write_json`: `feature_utils.create_empty_dataset_info`, `utils.DatasetInfo`
  (`from_dict` / `to_dict`: the fields in their order, shapes as lists), `utils/io_utils.write_json`;
- `load_stats`, `serialize_stats`, `aggregate_stats`: `io_utils.load_stats` / `cast_stats_to_numpy`,
  `utils.serialize_dict`, `compute_stats.aggregate_stats`;
- `arrow_schema`, `episode_table`: the Arrow schema (with its `huggingface` metadata) and table that
  `feature_utils.get_hf_features_from_features` and `datasets.Dataset.from_dict` give for numeric features of
  shape (1,) or (n,), the only ones a BAVO dataset stores in parquet;
- `read_tasks`, `write_tasks`: `io_utils.load_tasks` / `write_tasks` and `LeRobotDatasetMetadata.
  save_episode_tasks` (pandas, imported only when a task is added);
- `video_info`, `video_duration_s`, `concatenate_videos`: `video_utils.get_video_info`,
  `get_video_duration_in_s`, `concatenate_video_files` (PyAV);
- `last_episode`: the last row of `meta/episodes/`, what `LeRobotDatasetMetadata.episodes[-1]` gives a resumed
  writer;
- `card_template`: `utils.create_lerobot_dataset_card`'s template (the card itself: `card.write_card`).

`tests/test_lerobot_format.py` compares each with LeRobot's own function, and `tests/test_direct_writer.py`
the files of whole writer sessions with LeRobot's writer's, byte for byte, so an upgrade of LeRobot that
changes its format fails there (the pinned version is `lerobot==0.6.1`).
"""

from __future__ import annotations

import copy
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

CODEBASE_VERSION = "v3.0"
CHUNKS_SIZE = 1000  # DEFAULT_CHUNK_SIZE: files per chunk folder
DATA_FILES_SIZE_IN_MB = 100
VIDEO_FILES_SIZE_IN_MB = 200
DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
EPISODES_DIR = "meta/episodes"
EPISODES_PATH = EPISODES_DIR + "/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
METADATA_BUFFER_SIZE = 10  # episode rows LeRobot's metadata buffers before writing them
# the columns LeRobot adds to every dataset (lerobot.utils.constants.DEFAULT_FEATURES)
DEFAULT_FEATURES = {
    "timestamp": {"dtype": "float32", "shape": (1,), "names": None},
    "frame_index": {"dtype": "int64", "shape": (1,), "names": None},
    "episode_index": {"dtype": "int64", "shape": (1,), "names": None},
    "index": {"dtype": "int64", "shape": (1,), "names": None},
    "task_index": {"dtype": "int64", "shape": (1,), "names": None},
}
# DatasetInfo's fields in their order, with their defaults (None: required)
_INFO_FIELDS = (("codebase_version", None), ("fps", None), ("features", None), ("total_episodes", 0),
                ("total_frames", 0), ("total_tasks", 0), ("chunks_size", CHUNKS_SIZE),
                ("data_files_size_in_mb", DATA_FILES_SIZE_IN_MB),
                ("video_files_size_in_mb", VIDEO_FILES_SIZE_IN_MB), ("data_path", DATA_PATH),
                ("video_path", VIDEO_PATH), ("robot_type", None), ("splits", {}), ("tools", None))
_REQUIRED_INFO = ("codebase_version", "fps", "features")


class UnsupportedFeature(ValueError):
    """A feature this module cannot write as LeRobot would (images in parquet, strings, 2-D arrays, ...)."""


# ------------------------------------------------------------------ info.json
def normalized_info(raw: dict) -> dict:
    """`DatasetInfo.from_dict(raw).to_dict()`: the known fields in DatasetInfo's order (unknown ones dropped,
    missing ones defaulted, `tools` dropped when None), every feature shape a list. A copy."""
    missing = [k for k in _REQUIRED_INFO if k not in raw]
    if missing:
        raise ValueError(f"meta/info.json lacks {', '.join(missing)}")
    info = {}
    for name, default in _INFO_FIELDS:
        info[name] = copy.deepcopy(raw.get(name, default))
    if info["tools"] is None:
        del info["tools"]
    for ft in info["features"].values():
        if isinstance(ft.get("shape"), (tuple, list)):
            ft["shape"] = list(ft["shape"])
    if info["fps"] <= 0 or info["chunks_size"] <= 0 or info["data_files_size_in_mb"] <= 0 \
            or info["video_files_size_in_mb"] <= 0:
        raise ValueError(f"meta/info.json has a non-positive fps or file size: {info}")
    return info


def new_info(fps: int, features: dict, use_videos: bool, robot_type: str | None) -> dict:
    """The `meta/info.json` of a new dataset (`LeRobotDatasetMetadata.create`): `features` plus LeRobot's
    default columns, no episodes yet."""
    features = {**copy.deepcopy(features), **copy.deepcopy(DEFAULT_FEATURES)}
    bad = [name for name in features if "/" in name]
    if bad:
        raise ValueError(f"Feature names should not contain '/'. Found '/' in {bad}.")
    return normalized_info({"codebase_version": CODEBASE_VERSION, "fps": fps, "features": features,
                            "robot_type": robot_type, "video_path": VIDEO_PATH if use_videos else None})


def write_json(data, path: Path) -> None:
    """LeRobot's `write_json`: indent 4, UTF-8 as is; parent folders created."""
    path.parent.mkdir(exist_ok=True, parents=True)
    with open(path, "w", encoding="utf-8") as f:
        json.dump(data, f, indent=4, ensure_ascii=False)


def create_dataset(root: Path, fps: int, features: dict, use_videos: bool, robot_type: str | None) -> None:
    """What `LeRobotDataset.create(...)` then `finalize()` leave on disk: the folder (which must not exist)
    and `meta/info.json`."""
    root.mkdir(parents=True, exist_ok=False)
    write_json(new_info(fps, features, use_videos, robot_type), root / INFO_PATH)


def next_file(chunk_index: int, file_index: int, chunks_size: int) -> tuple[int, int]:
    """LeRobot's `update_chunk_file_indices`: the (chunk, file) after this one."""
    if file_index == chunks_size - 1:
        return chunk_index + 1, 0
    return chunk_index, file_index + 1


def size_in_mb(path: Path) -> float:
    return path.stat().st_size / (1024**2)


# ------------------------------------------------------------------ statistics
def flatten_dict(d: dict, parent_key: str = "", sep: str = "/") -> dict:
    """LeRobot's `flatten_dict`: nested keys joined with `sep`."""
    items = []
    for k, v in d.items():
        new_key = f"{parent_key}{sep}{k}" if parent_key else k
        if isinstance(v, dict):
            items.extend(flatten_dict(v, new_key, sep=sep).items())
        else:
            items.append((new_key, v))
    return dict(items)


def unflatten_dict(d: dict, sep: str = "/") -> dict:
    """LeRobot's `unflatten_dict`, the inverse of `flatten_dict`."""
    out: dict = {}
    for key, value in d.items():
        parts = key.split(sep)
        inner = out
        for part in parts[:-1]:
            inner = inner.setdefault(part, {})
        inner[parts[-1]] = value
    return out


def load_stats(root: Path) -> dict | None:
    """`meta/stats.json` as LeRobot's `load_stats` reads it (every value an at-least-1-D numpy array), or
    None when there is none."""
    path = Path(root) / STATS_PATH
    if not path.exists():
        return None
    stats = json.loads(path.read_text(encoding="utf-8"))
    return unflatten_dict({k: np.atleast_1d(np.array(v)) for k, v in flatten_dict(stats).items()})


def serialize_stats(stats: dict) -> dict:
    """LeRobot's `serialize_dict`: arrays as lists, numpy scalars as Python numbers."""
    out = {}
    for key, value in flatten_dict(stats).items():
        if isinstance(value, np.ndarray):
            out[key] = value.tolist()
        elif isinstance(value, list) and isinstance(value[0], (int | float | list)):
            out[key] = value
        elif isinstance(value, np.generic):
            out[key] = value.item()
        elif isinstance(value, (int | float)):
            out[key] = value
        else:
            raise NotImplementedError(f"The value '{value}' of type '{type(value)}' is not supported.")
    return unflatten_dict(out)


def write_stats(stats: dict, root: Path) -> None:
    write_json(serialize_stats(stats), Path(root) / STATS_PATH)


def _check_stat(value, key: str, feature: str) -> None:
    """LeRobot's `_validate_stat_value`."""
    if not isinstance(value, np.ndarray):
        raise ValueError(f"Stats must be composed of numpy array, but key '{key}' of feature '{feature}' "
                         f"is of type '{type(value)}' instead.")
    if value.ndim == 0:
        raise ValueError("Number of dimensions must be at least 1, and is 0 instead.")
    if key == "count" and value.shape != (1,):
        raise ValueError(f"Shape of 'count' must be (1), but is {value.shape} instead.")
    if "image" in feature and key != "count" and value.shape not in ((3, 1, 1), (1, 1, 1)):
        raise ValueError(
            f"Shape of quantile '{key}' must be (3,1,1) or (1,1,1) but is {value.shape} instead.")


def _aggregate_feature_stats(stats_ft_list: list[dict]) -> dict[str, np.ndarray]:
    """LeRobot's `aggregate_feature_stats`, operation for operation."""
    means = np.stack([s["mean"] for s in stats_ft_list])
    variances = np.stack([s["std"] ** 2 for s in stats_ft_list])
    counts = np.stack([s["count"] for s in stats_ft_list])
    total_count = counts.sum(axis=0)
    while counts.ndim < means.ndim:
        counts = np.expand_dims(counts, axis=-1)
    weighted_means = means * counts
    total_mean = weighted_means.sum(axis=0) / total_count
    delta_means = means - total_mean
    weighted_variances = (variances + delta_means**2) * counts
    total_variance = weighted_variances.sum(axis=0) / total_count
    aggregated = {
        "min": np.min(np.stack([s["min"] for s in stats_ft_list]), axis=0),
        "max": np.max(np.stack([s["max"] for s in stats_ft_list]), axis=0),
        "mean": total_mean,
        "std": np.sqrt(total_variance),
        "count": total_count,
    }
    if stats_ft_list:
        quantile_keys = [k for k in stats_ft_list[0] if k.startswith("q") and k[1:].isdigit()]
        for q_key in quantile_keys:
            if all(q_key in s for s in stats_ft_list):
                quantile_values = np.stack([s[q_key] for s in stats_ft_list])
                weighted_quantiles = quantile_values * counts
                aggregated[q_key] = weighted_quantiles.sum(axis=0) / total_count
    return aggregated


def aggregate_stats(stats_list: list[dict]) -> dict:
    """LeRobot's `aggregate_stats` (the same values; LeRobot's key order comes from a set, so it varies from
    run to run, and this one keeps the order keys first appear in)."""
    for stats in stats_list:
        for feature, feature_stats in stats.items():
            for key, value in feature_stats.items():
                _check_stat(value, key, feature)
    keys = list(dict.fromkeys(key for stats in stats_list for key in stats))
    return {key: _aggregate_feature_stats([s[key] for s in stats_list if key in s]) for key in keys}


# ------------------------------------------------------------------ parquet
def _arrow_type(dtype: str):
    import pyarrow as pa

    try:
        typ = pa.from_numpy_dtype(np.dtype(dtype))
    except (TypeError, pa.ArrowNotImplementedError):
        raise UnsupportedFeature(f"dtype {dtype!r}") from None
    if not (pa.types.is_integer(typ) or pa.types.is_floating(typ)):
        raise UnsupportedFeature(f"dtype {dtype!r}")
    return typ


def arrow_schema(features: dict):
    """The Arrow schema of the parquet rows of a dataset with `features` (LeRobot features; video features
    hold no column): what `get_hf_features_from_features(features).arrow_schema` gives, `huggingface` metadata
    included, for numeric features of shape (1,) (a value) or (n,) (a fixed-length list). UnsupportedFeature
    for anything else."""
    import pyarrow as pa

    fields, described = [], {}
    for key, ft in features.items():
        if ft["dtype"] == "video":
            continue
        if ft["dtype"] in ("image", "string", "language") or key.startswith("language"):
            raise UnsupportedFeature(f"feature {key!r} ({ft['dtype']})")
        typ = _arrow_type(ft["dtype"])
        value = {"dtype": ft["dtype"], "_type": "Value"}
        shape = tuple(ft["shape"])
        if shape == (1,):
            fields.append(pa.field(key, typ))
            described[key] = value
        elif len(shape) == 1:
            fields.append(pa.field(key, pa.list_(typ, shape[0])))
            described[key] = {"feature": value, "length": shape[0], "_type": "List"}
        else:
            raise UnsupportedFeature(f"feature {key!r} of shape {shape}")
    return pa.schema(fields, metadata={"huggingface": json.dumps({"info": {"features": described}})})


def episode_table(columns: dict, schema):
    """The Arrow table `datasets.Dataset.from_dict(columns, features=...)` holds for `schema`
    (`arrow_schema`), built directly, or None where that is not certain: every column a numpy array of n > 0
    rows with exactly the column's dtype and width (a plain float column may have another float dtype: it is
    cast as `datasets` casts it), named exactly by the schema."""
    import pyarrow as pa

    if not isinstance(columns, dict) or set(columns) != set(schema.names):
        return None
    arrays, n = [], None
    for name, typ in zip(schema.names, schema.types, strict=True):
        value = columns[name]
        if not isinstance(value, np.ndarray) or value.ndim == 0:
            return None
        if n is None:
            n = value.shape[0]
        if value.shape[0] != n or n == 0:
            return None
        if pa.types.is_fixed_size_list(typ):
            item = typ.value_type
            if not _numeric(item) or value.dtype != item.to_pandas_dtype() or value[0].size != typ.list_size:
                return None
            flat = pa.array(np.ascontiguousarray(value).reshape(-1), type=item)
            arrays.append(pa.FixedSizeListArray.from_arrays(flat, typ.list_size))
        elif _numeric(typ) and value.ndim == 1 and value.dtype == typ.to_pandas_dtype():
            arrays.append(pa.array(value, type=typ))
        elif pa.types.is_floating(typ) and value.ndim == 1 and value.dtype.kind == "f":
            arrays.append(pa.array(value).cast(typ))  # LeRobot's float64 timestamps for a float32 feature
        else:
            return None
    return pa.Table.from_arrays(arrays, schema=schema)


def _numeric(arrow_type) -> bool:
    import pyarrow as pa

    return pa.types.is_integer(arrow_type) or pa.types.is_floating(arrow_type)


def parquet_writer(path: Path, schema, use_dictionary: bool | list[str] = True):
    """LeRobot's parquet writer settings for data and episode files: snappy, dictionary encoding
    (`use_dictionary`: True for every column, as LeRobot; or the columns to dictionary-encode)."""
    import pyarrow.parquet as pq

    path.parent.mkdir(parents=True, exist_ok=True)
    return pq.ParquetWriter(path, schema=schema, compression="snappy", use_dictionary=use_dictionary)


def scalar_columns(schema) -> list[str]:
    """The columns of `schema` that hold one value per row (not lists)."""
    import pyarrow as pa

    return [f.name for f in schema if not (pa.types.is_fixed_size_list(f.type) or pa.types.is_list(f.type))]


def episode_rows_table(rows: list[dict]):
    """The episode-metadata table LeRobot's `_flush_metadata_buffer` writes for buffered episode dicts (each
    value a one-element list, as `_save_episode_metadata` wraps them)."""
    import pyarrow as pa

    combined: dict[str, list] = {}
    for episode in rows:
        for key, value in episode.items():
            val = value[0] if isinstance(value, list) else value
            combined.setdefault(key, []).append(val.tolist() if isinstance(val, np.ndarray) else val)
    return pa.Table.from_pydict(combined)


def read_frame_columns(root: Path, columns: list[str]):
    """`columns` of every frame of the dataset at `root` (its `data/*/*.parquet` files in order), as one Arrow
    table; FileNotFoundError when there are no data files."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    files = sorted((Path(root) / "data").glob("*/*.parquet"))
    if not files:
        raise FileNotFoundError(f"no data files under {Path(root) / 'data'}")
    return pa.concat_tables([pq.read_table(f, columns=columns) for f in files])


def last_episode(root: Path, columns: list[str]) -> dict:
    """`columns` of the last episode row of `meta/episodes/` (the last row of its last file), as a resumed
    LeRobot writer reads `meta.episodes[-1]`."""
    import pyarrow.parquet as pq

    files = sorted((Path(root) / EPISODES_DIR).glob("*/*.parquet"))
    if not files:
        raise FileNotFoundError(f"{Path(root) / EPISODES_DIR} holds no episode table")
    f = pq.ParquetFile(files[-1])
    table = f.read_row_group(f.num_row_groups - 1, columns=columns)
    return {name: table.column(name)[table.num_rows - 1].as_py() for name in columns}


# ------------------------------------------------------------------ tasks
def read_tasks(root: Path) -> list[str]:
    """The task descriptions of `meta/tasks.parquet`, by task index."""
    import pyarrow.parquet as pq

    table = pq.read_table(Path(root) / TASKS_PATH).to_pydict()
    order = sorted(range(len(table["task_index"])), key=lambda i: table["task_index"][i])
    return [table["task"][i] for i in order]


def write_tasks(root: Path, new_tasks: list[str], had_tasks: bool) -> None:
    """Add `new_tasks` to `meta/tasks.parquet` as `LeRobotDatasetMetadata.save_episode_tasks` does (with
    pandas: its DataFrame, `.loc` appends and `to_parquet`, so the same file); `had_tasks`: the file
    exists."""
    import pandas as pd

    path = Path(root) / TASKS_PATH
    if not had_tasks:
        tasks = pd.DataFrame({"task_index": range(len(new_tasks))}, index=pd.Index(new_tasks, name="task"))
    else:
        tasks = pd.read_parquet(path)
        tasks.index.name = "task"
        for task_idx, task in zip(range(len(tasks), len(tasks) + len(new_tasks)), new_tasks, strict=True):
            tasks.loc[task] = task_idx
    path.parent.mkdir(parents=True, exist_ok=True)
    tasks.to_parquet(path)


# ------------------------------------------------------------------ card
def card_template() -> str:
    """LeRobot's dataset card template (`lerobot/datasets/card_template.md`), found without importing
    `lerobot.datasets` (`create_lerobot_dataset_card` reads it through `importlib.resources`)."""
    import importlib.util

    spec = importlib.util.find_spec("lerobot")
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError("lerobot is not installed")
    return (Path(next(iter(spec.submodule_search_locations))) / "datasets" / "card_template.md").read_text()


# ------------------------------------------------------------------ videos
def video_duration_s(path: Path) -> float:
    """LeRobot's `get_video_duration_in_s`."""
    import av

    with av.open(str(path)) as container:
        stream = container.streams.video[0]
        if stream.duration is not None:
            return float(stream.duration * stream.time_base)
        return float(container.duration / av.time_base)


def video_info(path: Path, encoder: dict | None) -> dict:
    """LeRobot's `get_video_info(path, video_encoder)` for an RGB encoder whose fields (`dataclasses.asdict`)
    are `encoder`: the stream's properties, the audio's (none), the encoder's fields as `video.<field>`."""
    import av

    info: dict = {}
    with av.open(str(path), "r") as f:
        if not f.streams.video:
            return {}
        stream = f.streams.video[0]
        info["video.height"] = stream.height
        info["video.width"] = stream.width
        info["video.codec"] = stream.codec.canonical_name
        info["video.pix_fmt"] = stream.pix_fmt
        info["video.fps"] = int(stream.base_rate)
        info["video.channels"] = len(av.VideoFormat(stream.pix_fmt).components)
    info.update(_audio_info(path))
    for name, value in (encoder or {}).items():
        if name != "vcodec":
            info.setdefault(f"video.{name}", value)
    info["is_depth_map"] = False
    return info


def _audio_info(path: Path) -> dict:
    """LeRobot's `get_audio_info`."""
    import av

    with av.open(str(path), "r") as f:
        if not f.streams.audio:
            return {"has_audio": False}
        stream = f.streams.audio[0]
        return {"audio.channels": stream.channels, "audio.codec": stream.codec.canonical_name,
                "audio.bit_rate": stream.bit_rate, "audio.sample_rate": stream.sample_rate,
                "audio.bit_depth": stream.format.bits, "audio.channel_layout": stream.layout.name,
                "has_audio": True}


def concatenate_videos(inputs: list[Path], output: Path) -> None:
    """LeRobot's `concatenate_video_files(inputs, output)`: FFmpeg's concat demuxer, packets copied into a
    `faststart` mp4 (no re-encoding), written to a temporary file and moved onto `output`."""
    import av

    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(mode="w", suffix=".ffconcat", delete=False) as listing:
        listing.write("ffconcat version 1.0\n")
        for path in inputs:
            listing.write(f"file '{str(Path(path).resolve())}'\n")
        listing.flush()
        listing_path = listing.name
    source = av.open(listing_path, mode="r", format="concat", options={"safe": "0"})
    with tempfile.NamedTemporaryFile(suffix=".mp4", delete=False) as tmp:
        tmp_path = tmp.name
    target = av.open(tmp_path, mode="w", options={"movflags": "faststart"})
    streams = {}
    for stream in source.streams:
        if stream.type in ("video", "audio", "subtitle"):
            streams[stream.index] = target.add_stream_from_template(template=stream, opaque=True)
            streams[stream.index].time_base = stream.time_base
    for packet in source.demux():
        if packet.stream.index not in streams or packet.dts is None:
            continue
        packet.stream = streams[packet.stream.index]
        target.mux(packet)
    source.close()
    target.close()
    shutil.move(tmp_path, output)
    Path(listing_path).unlink()
