"""In-memory sample loading for `lerobot-train` on BAVO training views (the fast data path).

Why: LeRobot 0.6.1 reads every training sample row by row from the Arrow table through
`datasets` (`DatasetReader.get_item`), and answers each `delta_timestamps` window with one more
query per key. For a ManiFlow/A-FAR sample of the `points` view (2 observation steps of state,
cloud and four teacher features, 16 actions) that costs more than the policy's own training step
at the `cpu_fast` preset on 2-core machines (docs/results/costs.md). The data of a training view
is small enough to hold in memory, so every column is read once, as contiguous tensors, and a
sample becomes a few index operations.

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

from lerobot_bavo.datasets.lerobot_private import (
    dataset_is_finalized,
    install_dataset_class,
    reader_image_transforms,
    reader_metadata,
)

logger = logging.getLogger(__name__)

ENV_OPT_OUT = "BAVO_FAST_DATASET"
_BOOKKEEPING = ("timestamp", "frame_index", "episode_index", "index", "task_index")


def column_array(column: pa.ChunkedArray) -> np.ndarray:
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
    if reader_image_transforms(reader) is not None:
        return "it has image transforms"
    for name, field in zip(reader.hf_dataset.data.schema.names, reader.hf_dataset.data.schema.types):
        t = field
        while pa.types.is_fixed_size_list(t):
            t = t.value_type
        if not (pa.types.is_floating(t) or pa.types.is_integer(t) or pa.types.is_boolean(t)):
            return f"column {name!r} has type {field}"
    return None


class InMemoryReader:
    """Serves `LeRobotDataset.__getitem__` (and whole batches) from tensors held in memory; same items as
    LeRobot's reader.

    Wraps (and delegates everything else to) the dataset's own `DatasetReader`, so `hf_dataset`,
    `episodes`, `num_frames` and the rest are LeRobot's.

    The columns are CPU torch tensors so that a DataLoader worker started with `spawn` (LeRobot's default,
    `--num_workers=4`) receives them through torch's shared-memory pickling instead of a byte copy per worker.
    """

    def __init__(self, reader):
        self._reader = reader
        table = reader.hf_dataset.data
        self.columns = {
            name: torch.from_numpy(column_array(table.column(name))) for name in table.column_names
        }
        meta = reader_metadata(reader)
        # Episode bounds in absolute frame indices, as LeRobot's `_get_query_indices` reads them.
        eps = meta.episodes
        self._ep_from = torch.as_tensor(np.asarray(eps["dataset_from_index"], dtype=np.int64))
        self._ep_to = torch.as_tensor(np.asarray(eps["dataset_to_index"], dtype=np.int64))
        abs_idx = self.columns["index"].to(torch.int64)
        self._abs = abs_idx
        # absolute -> relative row (episode-filtered datasets hold a subset of rows): a dense lookup table
        self._first = int(abs_idx[0]) if len(abs_idx) else 0
        self._contiguous = bool(
            len(abs_idx) == 0 or torch.equal(abs_idx, torch.arange(self._first, self._first + len(abs_idx)))
        )
        self._rel = None
        if not self._contiguous:
            self._rel = torch.full((int(abs_idx.max()) - self._first + 1,), -1, dtype=torch.int64)
            self._rel[abs_idx - self._first] = torch.arange(len(abs_idx))
        self._delta = (
            {k: torch.as_tensor(np.asarray(v, dtype=np.int64)) for k, v in reader.delta_indices.items()}
            if reader.delta_indices is not None else None
        )
        self._task_names = [str(name) for name in meta.tasks.index]

    def __getattr__(self, name):  # everything but the item methods is LeRobot's reader
        if name.startswith("__") or name == "_reader":  # pickling looks these up before __dict__ is restored
            raise AttributeError(name)
        return getattr(self._reader, name)

    def _relative(self, absolute: torch.Tensor) -> torch.Tensor:
        if self._contiguous:
            return absolute - self._first
        return self._rel[absolute - self._first]

    def get_batch(self, indices) -> dict:
        """The items of relative rows `indices`, stacked: each key (B, ...), `<key>_is_pad` (B, K), and `task`
        a list of B strings. One gather per column for the whole batch."""
        idx = torch.as_tensor(np.asarray(indices, dtype=np.int64)).reshape(-1)
        cols = self.columns
        batch = {key: col[idx] for key, col in cols.items()}
        if self._delta is not None:
            ep = cols["episode_index"][idx].to(torch.int64)
            abs_idx = self._abs[idx]
            start, end = self._ep_from[ep][:, None], self._ep_to[ep][:, None]
            for key, delta in self._delta.items():
                target = abs_idx[:, None] + delta[None]
                batch[f"{key}_is_pad"] = (target < start) | (target >= end)
                if key in cols:
                    rows = self._relative(torch.minimum(torch.maximum(target, start), end - 1))
                    batch[key] = cols[key][rows]
        batch["task"] = [self._task_names[int(t)] for t in cols["task_index"][idx]]
        return batch

    def get_items(self, indices) -> list[dict]:
        """LeRobot's items for relative rows `indices` (what a DataLoader batch asks for), gathered in one
        step (`get_batch`) and handed out as per-item views for the DataLoader's collate function."""
        batch = self.get_batch(indices)
        keys = list(batch)
        return [{k: batch[k][i] for k in keys} for i in range(len(batch["task"]))]

    def get_item(self, idx) -> dict:
        """LeRobot's item for relative row `idx`: the row, each delta window clamped to the episode with its
        `<key>_is_pad` flags, and the task string (`DatasetReader.get_item`, without video)."""
        return self.get_items([int(idx)])[0]


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


_IN_MEMORY_CLASS = None


def in_memory_dataset_class():
    """`InMemoryLeRobotDataset`: LeRobot's `LeRobotDataset`, whose samples come from memory when
    `use_in_memory_reader` accepts it, and which hands a DataLoader whole batches (`__getitems__`).

    Built on first use (it subclasses LeRobot's class, and `import lerobot_bavo` must not import LeRobot) and
    reachable as `lerobot_bavo.datasets.fast.InMemoryLeRobotDataset`, so that pickle finds it in the
    DataLoader workers LeRobot starts with `spawn`.
    """
    global _IN_MEMORY_CLASS
    if _IN_MEMORY_CLASS is not None:
        return _IN_MEMORY_CLASS
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    class InMemoryLeRobotDataset(LeRobotDataset):

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            use_in_memory_reader(self)

        def __getitems__(self, indices: list[int]) -> list[dict]:
            """A DataLoader batch in one gather (torch's fetcher calls this instead of `__getitem__` per
            index)."""
            if isinstance(self.reader, InMemoryReader) and (
                self.writer is None or dataset_is_finalized(self)
            ):
                return self.reader.get_items(indices)
            return [self[i] for i in indices]

    InMemoryLeRobotDataset.__doc__ = in_memory_dataset_class.__doc__
    InMemoryLeRobotDataset.__module__ = __name__
    InMemoryLeRobotDataset.__qualname__ = "InMemoryLeRobotDataset"
    InMemoryLeRobotDataset.__name__ = "LeRobotDataset"  # what LeRobot's logs and reprs show
    _IN_MEMORY_CLASS = InMemoryLeRobotDataset
    return InMemoryLeRobotDataset


def __getattr__(name: str):
    if name == "InMemoryLeRobotDataset":
        return in_memory_dataset_class()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def install_lerobot_train_hook() -> bool:
    """Make the `LeRobotDataset`s built by LeRobot's dataset factory (`lerobot-train`) use the in-memory
    reader.

    The factory module (`lerobot.datasets.factory`) looks `LeRobotDataset` up as a module global when it
    builds the train (and eval) datasets; it is replaced there, and only there, by `InMemoryLeRobotDataset`,
    which swaps the reader after LeRobot's own constructor ran (`lerobot_private.install_dataset_class`).
    Idempotent; does nothing with `BAVO_FAST_DATASET=0`.
    """
    if os.environ.get(ENV_OPT_OUT, "1").strip().lower() in ("0", "false", "no", "off"):
        return False
    install_dataset_class(in_memory_dataset_class())
    return True
