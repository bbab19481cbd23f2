"""In-memory sample loading for `lerobot-train` on BAVO training views (the fast data path).

Why: LeRobot 0.6.1 reads every training sample row by row from the Arrow table through
`datasets` (`DatasetReader.get_item`), and answers each `delta_timestamps` window with one more
query per key. For a ManiFlow/A-FAR sample of the `points` view (2 observation steps of state,
cloud and four teacher features, 16 actions) that costs ~10-26 ms on these 2-core machines,
more than the policy's own training step at the `cpu_fast` preset. The data of a training view
is small enough to hold in memory (the 100-episode Cube Handoff points view is ~0.7 GB as
float32), so every column is read once, as contiguous tensors, and a sample becomes a few index
operations (well under 1 ms).

What stays LeRobot's: the `LeRobotDataset` object itself (metadata, episodes, stats, samplers,
everything `lerobot-train` touches); only its reader's `get_item` is replaced by
`InMemoryReader.get_item`, which returns exactly the item LeRobot's returns (same keys, values,
dtypes, shapes, the same clamping to the episode and `*_is_pad` flags; a test compares them).

When it is used: `lerobot-train` imports our plugin module `lerobot_env_bavo`, which calls
`install_lerobot_train_hook()`; every `LeRobotDataset` that LeRobot's dataset factory builds
then gets the in-memory reader if it qualifies (no video or image features, no image
transforms, only fixed-size numeric columns; a BAVO training view: `python -m
lerobot_bavo.datasets.views --view points|state`). Anything else goes through LeRobot
unchanged. Opt out with `BAVO_FAST_DATASET=0`. `import lerobot_bavo` alone installs nothing.
"""

from __future__ import annotations

import logging
import os

import numpy as np
import pyarrow as pa
import torch

logger = logging.getLogger(__name__)

ENV_OPT_OUT = "BAVO_FAST_DATASET"
_BOOKKEEPING = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def _column_array(column: pa.ChunkedArray) -> np.ndarray:
    """An Arrow column of scalars or fixed-size lists -> one contiguous array (rows, ...), in memory."""
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    shape = [len(arr)]
    while pa.types.is_fixed_size_list(arr.type):
        shape.append(arr.type.list_size)
        if arr.offset or arr.null_count:  # slices/nulls: go through Python values, still exact
            return np.array(arr.to_pylist())
        arr = arr.values
    if arr.null_count:
        raise ValueError("column has nulls")
    # A copy: the table is memory-mapped from the parquet cache, whose pages would otherwise be faulted in
    # sample by sample (and Arrow buffers are read-only).
    return np.array(arr.to_numpy(zero_copy_only=False), copy=True).reshape(shape)


def supports(dataset) -> str | None:
    """None if `dataset` can be served from memory, else the reason why not."""
    meta = dataset.meta
    if meta.video_keys or meta.camera_keys:
        return f"it has image/video features {list(meta.camera_keys)}"
    reader = getattr(dataset, "reader", None)
    if reader is None or getattr(reader, "hf_dataset", None) is None:
        return "its data is not loaded"
    if getattr(reader, "_image_transforms", None) is not None:
        return "it has image transforms"
    for name, field in zip(reader.hf_dataset.data.schema.names, reader.hf_dataset.data.schema.types):
        t = field
        while pa.types.is_fixed_size_list(t):
            t = t.value_type
        if not (pa.types.is_floating(t) or pa.types.is_integer(t) or pa.types.is_boolean(t)):
            return f"column {name!r} has type {field}"
    return None


class InMemoryReader:
    """Serves `LeRobotDataset.__getitem__` from tensors held in memory; same items as LeRobot's reader.

    Wraps (and delegates everything else to) the dataset's own `DatasetReader`, so `hf_dataset`,
    `episodes`, `num_frames` and the rest are LeRobot's.
    """

    def __init__(self, reader):
        self._reader = reader
        table = reader.hf_dataset.data
        # numpy, not torch: a sample is a few small fancy-indexing copies, which torch would spread over its
        # intra-op threads (and stall for ms when the training process keeps the cores busy).
        self.columns = {name: _column_array(table.column(name)) for name in table.column_names}
        meta = reader._meta
        # Episode bounds in absolute frame indices, as LeRobot's `_get_query_indices` reads them.
        eps = meta.episodes
        self._ep_from = np.asarray(eps["dataset_from_index"], dtype=np.int64)
        self._ep_to = np.asarray(eps["dataset_to_index"], dtype=np.int64)
        abs_np = self.columns["index"]
        # absolute -> relative row (episode-filtered datasets hold a subset of rows)
        self._contiguous = bool(len(abs_np) == 0 or np.array_equal(abs_np, np.arange(abs_np[0], abs_np[0] + len(abs_np))))
        self._first = int(abs_np[0]) if len(abs_np) else 0
        if not self._contiguous:
            self._rel = {int(a): i for i, a in enumerate(abs_np)}
        self._delta = (
            {k: np.asarray(v, dtype=np.int64) for k, v in reader.delta_indices.items()}
            if reader.delta_indices is not None else None
        )
        self._tasks = meta.tasks

    def __getattr__(self, name):  # everything but get_item is LeRobot's reader
        return getattr(self._reader, name)

    def _relative(self, absolute: np.ndarray) -> np.ndarray:
        if self._contiguous:
            return absolute - self._first
        return np.array([self._rel[int(a)] for a in absolute], dtype=np.int64)

    def get_item(self, idx) -> dict:
        """LeRobot's item for relative row `idx`: the row, each delta window clamped to the episode with its
        `<key>_is_pad` flags, and the task string (`DatasetReader.get_item`, without video)."""
        idx = int(idx)
        cols = self.columns
        item = {key: torch.from_numpy(np.array(col[idx])) for key, col in cols.items()}
        if self._delta is not None:
            ep_idx = int(cols["episode_index"][idx])
            abs_idx = int(cols["index"][idx])
            start, end = int(self._ep_from[ep_idx]), int(self._ep_to[ep_idx])
            for key, delta in self._delta.items():
                target = abs_idx + delta
                item[f"{key}_is_pad"] = torch.from_numpy((target < start) | (target >= end))
                if key in cols:
                    item[key] = torch.from_numpy(cols[key][self._relative(np.clip(target, start, end - 1))])
        item["task"] = self._tasks.iloc[int(cols["task_index"][idx])].name
        return item


def use_in_memory_reader(dataset) -> bool:
    """Give `dataset` (a `LeRobotDataset`) the in-memory reader if it qualifies; returns whether it did."""
    reason = supports(dataset)
    if reason is not None:
        logger.info("BAVO fast data path not used for %s: %s", getattr(dataset, "repo_id", "?"), reason)
        return False
    dataset.reader = InMemoryReader(dataset.reader)
    n_bytes = sum(a.nbytes for a in dataset.reader.columns.values())
    logger.info("BAVO fast data path: %s held in memory (%d frames, %.0f MB; opt out with %s=0)",
                dataset.repo_id, dataset.num_frames, n_bytes / 1e6, ENV_OPT_OUT)
    return True


def install_lerobot_train_hook() -> bool:
    """Make the `LeRobotDataset`s built by LeRobot's dataset factory (`lerobot-train`) use the in-memory reader.

    The factory module (`lerobot.datasets.factory`) looks `LeRobotDataset` up as a module global when it
    builds the train (and eval) datasets; it is replaced there, and only there, by a subclass that swaps the
    reader after LeRobot's own constructor ran. Idempotent; does nothing with `BAVO_FAST_DATASET=0`.
    """
    if os.environ.get(ENV_OPT_OUT, "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    from lerobot.datasets import factory
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if getattr(factory.LeRobotDataset, "_bavo_in_memory", False):
        return True

    class InMemoryLeRobotDataset(LeRobotDataset):
        """LeRobot's dataset; its samples come from memory when `use_in_memory_reader` accepts it."""

        _bavo_in_memory = True

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            use_in_memory_reader(self)

    InMemoryLeRobotDataset.__name__ = InMemoryLeRobotDataset.__qualname__ = "LeRobotDataset"
    factory.LeRobotDataset = InMemoryLeRobotDataset
    return True
