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

Whole batches: the dataset class also answers torch's `__getitems__` (a DataLoader batch of indices) with one
vectorised gather per column (`ColumnStore.gather`: the window offsets of `delta_timestamps`, the clamping to
the episode and `*_is_pad` as index arithmetic), already collated (`GatheredItems`, which torch's
`default_collate` hands through unchanged), so no per-sample Python runs, with any `--num_workers`.

Device-resident batches: on a GPU the training step waits for the host, and gathering, collating, pinning and
copying a batch is part of the host's work (gather and collate alone took 22.7 ms of one core at batch 512
item by item, 6.9 ms in one step; docs/gpu.md). So when
- the batch is fetched in lerobot-train's own process (`--num_workers=0`; CUDA tensors cannot come out of
  DataLoader worker processes, and those keep gathering on the CPU), and
- lerobot-train trains on CUDA (the device of the `accelerate.Accelerator` it built, `--policy.device`), and
- the view's columns take at most `BAVO_DEVICE_BATCHES` (default 0.25) of that device's free memory,
the columns are copied to the device once, at the first batch, and every batch is gathered there: a
`DeviceBatch` comes out of the DataLoader with no host-to-device copy of the data (only the B indices go
over). On a CUDA accelerator one log line says which was chosen and the memory it takes.
`BAVO_DEVICE_BATCHES=0` keeps batches on the CPU. Everywhere else (CPU training, workers, no `Accelerator`)
batches are gathered on the CPU as before.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence

import numpy as np
import pyarrow as pa
import torch
from torch.utils.data import get_worker_info
from torch.utils.data._utils.collate import collate, default_collate_fn_map

from lerobot_bavo.datasets.lerobot_private import (
    dataset_is_finalized,
    install_dataset_class,
    reader_image_transforms,
    reader_metadata,
)

logger = logging.getLogger(__name__)

ENV_OPT_OUT = "BAVO_FAST_DATASET"
ENV_DEVICE_BATCHES = "BAVO_DEVICE_BATCHES"
DEFAULT_DEVICE_SHARE = 0.25  # of the training device's free memory the columns may take
CPU = torch.device("cpu")


def column_array(column: pa.ChunkedArray) -> np.ndarray:
    """An Arrow column of scalars or lists -> one contiguous array (rows, ...), in memory.

    Lists are fixed-size in the files LeRobot and `bavo-collect` write; LeRobot's `merge_datasets` writes
    variable-size ones (`list<float>`), read here when every row has the same length."""
    arr = column.combine_chunks() if isinstance(column, pa.ChunkedArray) else column
    shape = [len(arr)]
    while True:
        if pa.types.is_fixed_size_list(arr.type):
            shape.append(arr.type.list_size)
            if arr.offset or arr.null_count:  # slices/nulls: go through Python values, still exact
                return np.array(arr.to_pylist())
            arr = arr.values
        elif pa.types.is_list(arr.type) or pa.types.is_large_list(arr.type):
            if arr.null_count:
                raise ValueError("column has nulls")
            lengths = np.unique(arr.value_lengths().to_numpy(zero_copy_only=False))
            if len(lengths) > 1:
                raise ValueError(f"column's lists differ in length ({lengths.tolist()}): not an array")
            shape.append(int(lengths[0]) if len(lengths) else 0)
            arr = arr.flatten()  # the rows' values, offsets and slices applied
        else:
            break
    if arr.null_count:
        raise ValueError("column has nulls")
    # A copy: the table is memory-mapped from the parquet cache, whose pages would otherwise be faulted in
    # sample by sample (and Arrow buffers are read-only).
    return np.array(arr.to_numpy(zero_copy_only=False), copy=True).reshape(shape)


def device_batches_share() -> float:
    """The share of the training device's free memory that a view's columns may take to be held there
    (`BAVO_DEVICE_BATCHES`: a number in [0, 1]; 0 or off: always gather on the CPU); 0.25 when unset."""
    text = os.environ.get(ENV_DEVICE_BATCHES, "").strip().lower()
    if not text:
        return DEFAULT_DEVICE_SHARE
    if text in ("off", "false", "no"):
        return 0.0
    try:
        share = float(text)
    except ValueError:
        share = -1.0
    if not 0.0 <= share <= 1.0:
        raise ValueError(
            f"{ENV_DEVICE_BATCHES}={text!r}: expected a share of free device memory in [0, 1], or off"
        )
    return share


def training_device() -> torch.device | None:
    """The device lerobot-train trains on: that of the `accelerate.Accelerator` it built in this process (it
    does so before it builds the DataLoader; `--policy.device=cpu` makes it the CPU), or None where none was
    built."""
    try:
        from accelerate.state import PartialState, is_initialized
    except ImportError:  # pragma: no cover - a LeRobot dependency
        return None
    return torch.device(PartialState().device) if is_initialized() else None


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


class ColumnStore:
    """The tensors a batch gather reads, all on one device: the columns, the episode bounds, the absolute ->
    relative row map and the `delta_timestamps` windows. `gather` serves a whole batch in one vectorised step,
    on whichever device the store lives."""

    def __init__(self, columns: dict[str, torch.Tensor], ep_from: torch.Tensor, ep_to: torch.Tensor,
                 rel: torch.Tensor | None, first: int, delta: dict[str, tuple[int, ...]] | None):
        self.columns = columns
        self.ep_from, self.ep_to = ep_from, ep_to  # (episodes,) absolute frame bounds, end exclusive
        self.rel, self.first = rel, first  # rel None: the rows hold absolute indices first, first + 1, ...
        self.absolute = columns["index"].to(torch.int64)
        self.delta = delta  # key -> frame offsets of its window (LeRobot's `delta_indices`), or None
        # Keys with the same offsets (ManiFlow's observation keys share theirs) share the index arithmetic.
        self.windows = {
            offsets: torch.tensor(offsets, dtype=torch.int64, device=self.absolute.device)
            for offsets in dict.fromkeys((delta or {}).values())
        }

    @property
    def device(self) -> torch.device:
        return self.absolute.device

    @property
    def nbytes(self) -> int:
        """Bytes held: columns, index tables and window offsets."""
        tensors = [*self.columns.values(), self.absolute, self.ep_from, self.ep_to, *self.windows.values()]
        tensors += [self.rel] if self.rel is not None else []
        return sum(t.nbytes for t in tensors)

    def to(self, device) -> ColumnStore:
        """A copy on `device` (tensors already there are shared, not copied)."""
        columns = {k: c.to(device) for k, c in self.columns.items()}
        rel = None if self.rel is None else self.rel.to(device)
        ep_from, ep_to = self.ep_from.to(device), self.ep_to.to(device)
        return ColumnStore(columns, ep_from, ep_to, rel, self.first, self.delta)

    def relative(self, absolute: torch.Tensor) -> torch.Tensor:
        """Absolute frame indices -> rows of the columns."""
        return absolute - self.first if self.rel is None else self.rel[absolute - self.first]

    def gather(self, idx: torch.Tensor) -> dict[str, torch.Tensor]:
        """Rows `idx` (B,), on this store's device -> each column (B, ...); with `delta_timestamps`, each
        windowed key (B, K, ...) with its window clamped to the episode and `<key>_is_pad` (B, K): LeRobot's
        items for these rows, collated (without `task`), keys in the items' order. Index arithmetic only, with
        no per-sample Python and no host read, so on CUDA it is queued like any other kernel."""
        cols, delta = self.columns, self.delta or {}
        # windowed columns are filled below, in their place
        batch = {key: None if key in delta else col[idx] for key, col in cols.items()}
        if delta:
            abs_idx = self.absolute[idx][:, None]
            ep = cols["episode_index"][idx].to(torch.int64)
            start, end = self.ep_from[ep][:, None], self.ep_to[ep][:, None]
            windows = {}  # offsets -> (rows (B, K), is_pad (B, K))
            for offsets, steps in self.windows.items():
                target = abs_idx + steps[None]
                is_pad = (target < start) | (target >= end)
                windows[offsets] = self.relative(torch.minimum(torch.maximum(target, start), end - 1)), is_pad
            shared = set()
            for key, offsets in delta.items():
                rows, is_pad = windows[offsets]
                # each key its own flags, as collating LeRobot's items gives
                batch[f"{key}_is_pad"] = is_pad.clone() if offsets in shared else is_pad
                shared.add(offsets)
                if key in cols:
                    batch[key] = cols[key][rows]
        return batch


class DeviceBatch(dict):
    """A collated batch whose tensors already live on the training device (`InMemoryReader.get_batch` with
    a CUDA device). A DataLoader with `pin_memory=True` (lerobot-train's on CUDA) pins what it fetched by
    calling the batch's own `pin_memory()`; pinning is for CPU tensors, so here it returns the batch as it
    is."""

    def pin_memory(self, device=None) -> DeviceBatch:  # noqa: ARG002 (torch's pin_memory signature)
        return self


class InMemoryReader:
    """Serves `LeRobotDataset.__getitem__` (and whole batches) from tensors held in memory; same items as
    LeRobot's reader.

    Wraps (and delegates everything else to) the dataset's own `DatasetReader`, so `hf_dataset`,
    `episodes`, `num_frames` and the rest are LeRobot's.

    The columns are CPU torch tensors so that a DataLoader worker started with `spawn` (LeRobot's default,
    `--num_workers=4`) receives them through torch's shared-memory pickling instead of a byte copy per worker.
    A copy on the training device (`hold_on`, see "Device-resident batches" in the module docstring) stays in
    the process that made it: it is not pickled.
    """

    def __init__(self, reader):
        self._reader = reader
        table = reader.hf_dataset.data
        self.columns = {
            name: torch.from_numpy(column_array(table.column(name))) for name in table.column_names
        }
        meta = reader_metadata(reader)
        self.repo_id = meta.repo_id
        # Episode bounds in absolute frame indices, as LeRobot's `_get_query_indices` reads them.
        eps = meta.episodes
        ep_from = torch.as_tensor(np.asarray(eps["dataset_from_index"], dtype=np.int64))
        ep_to = torch.as_tensor(np.asarray(eps["dataset_to_index"], dtype=np.int64))
        abs_idx = self.columns["index"].to(torch.int64)
        # absolute -> relative row (episode-filtered datasets hold a subset of rows): a dense lookup table
        first = int(abs_idx[0]) if len(abs_idx) else 0
        contiguous = bool(
            len(abs_idx) == 0 or torch.equal(abs_idx, torch.arange(first, first + len(abs_idx)))
        )
        rel = None
        if not contiguous:
            rel = torch.full((int(abs_idx.max()) - first + 1,), -1, dtype=torch.int64)
            rel[abs_idx - first] = torch.arange(len(abs_idx))
        delta = (
            {k: tuple(int(d) for d in v) for k, v in reader.delta_indices.items()}
            if reader.delta_indices is not None else None
        )
        self.store = ColumnStore(self.columns, ep_from, ep_to, rel, first, delta)
        self._task_names = [str(name) for name in meta.tasks.index]
        self._device_store: ColumnStore | None = None  # the copy on the training device, if any
        self._device_decided = False  # whether `batch_device` has applied its rule in this process

    def __getattr__(self, name):  # everything but the item methods is LeRobot's reader
        if name.startswith("__") or name == "_reader":  # pickling looks these up before __dict__ is restored
            raise AttributeError(name)
        return getattr(self._reader, name)

    def __getstate__(self) -> dict:
        """Pickled (for DataLoader workers) without the device copy: CUDA tensors cannot go through worker
        processes, and workers gather on the CPU."""
        state = dict(self.__dict__)
        state["_device_store"], state["_device_decided"] = None, False
        return state

    def hold_on(self, device) -> ColumnStore:
        """Hold a copy of the columns on `device` (once; the CPU columns stay) and return it."""
        device = torch.device(device)
        if device.type == "cpu":
            return self.store
        if device.type == "cuda" and device.index is None:  # "cuda" and "cuda:0" are one copy
            device = torch.device("cuda", torch.cuda.current_device())
        if self._device_store is None or self._device_store.device != device:
            self._device_store = self.store.to(device)
        return self._device_store

    def batch_device(self) -> torch.device:
        """Where a DataLoader batch fetched in this process is gathered: the training device when the rule
        of "Device-resident batches" (module docstring) holds, else the CPU. Decided once per process, at the
        first batch fetched after lerobot-train built its `Accelerator`, and logged."""
        if self._device_store is not None:
            return self._device_store.device
        if self._device_decided or get_worker_info() is not None:  # workers gather on the CPU
            return CPU
        device = training_device()
        if device is None:  # no Accelerator (yet) in this process: not decided
            return CPU
        self._device_decided = True
        if device.type != "cuda":
            return CPU
        share = device_batches_share()
        need = self.store.nbytes
        if share <= 0:
            logger.info("BAVO device batches off (%s=0): %s batches gathered on the CPU", ENV_DEVICE_BATCHES,
                        self.repo_id)
            return CPU
        free, _ = torch.cuda.mem_get_info(device)
        if need > share * free:
            logger.info("BAVO device batches: %s not held on %s: its columns take %.1f MB, over %s=%g of the "
                        "%.1f MB free; batches gathered on the CPU", self.repo_id, device, need / 1e6,
                        ENV_DEVICE_BATCHES, share, free / 1e6)
            return CPU
        self.hold_on(device)
        logger.info("BAVO device batches: %s held on %s (%.1f MB of its %.0f MB free, limit %s=%g), "
                    "batches gathered there (DataLoader num_workers=0; %s=0 gathers on the CPU)",
                    self.repo_id, device, need / 1e6, free / 1e6, ENV_DEVICE_BATCHES, share,
                    ENV_DEVICE_BATCHES)
        return device

    def get_batch(self, indices, device=None) -> dict:
        """The items of relative rows `indices`, collated as torch's `default_collate` collates LeRobot's
        items: each key (B, ...), `<key>_is_pad` (B, K), and `task` a list of B strings. One vectorised gather
        for the whole batch (`ColumnStore.gather`), on the CPU (a plain dict) or on `device` (a `DeviceBatch`;
        the columns are copied there on first use, `hold_on`)."""
        idx = torch.as_tensor(np.asarray(indices, dtype=np.int64)).reshape(-1)
        store = self.store if device is None else self.hold_on(device)
        if store.device.type == "cpu":
            batch = store.gather(idx)
        else:
            # the B indices are all that crosses over: from pinned memory (torch's caching host allocator
            # keeps the buffer until the copy is done), so the copy is queued without waiting for the device
            sent = idx.pin_memory() if store.device.type == "cuda" else idx
            batch = DeviceBatch(store.gather(sent.to(store.device, non_blocking=True)))
        names = self._task_names
        # from the CPU column: the strings need no read from the device
        batch["task"] = ([names[0]] * len(idx) if len(names) == 1
                         else [names[t] for t in self.columns["task_index"][idx].tolist()])
        return batch

    def get_items(self, indices) -> list[dict]:
        """LeRobot's items for relative rows `indices`, gathered in one step (`get_batch`, on the CPU) and
        handed out as per-item views."""
        batch = self.get_batch(indices)
        keys = list(batch)
        return [{k: batch[k][i] for k in keys} for i in range(len(batch["task"]))]

    def get_item(self, idx) -> dict:
        """LeRobot's item for relative row `idx`: the row, each delta window clamped to the episode with its
        `<key>_is_pad` flags, and the task string (`DatasetReader.get_item`, without video)."""
        return self.get_items([int(idx)])[0]


class GatheredItems(Sequence):
    """What `InMemoryLeRobotDataset.__getitems__` hands a DataLoader: its B items, already gathered and
    collated (`batch`). torch's `default_collate` (lerobot-train's collate for these datasets) returns `batch`
    as it is (`collate_gathered_items`, registered in torch's `default_collate_fn_map`, the extension point
    its docstring names), so a batch costs no per-sample Python. Other collate functions see a sequence of
    per-item dicts (`GatheredRow`, views of `batch`)."""

    def __init__(self, batch: dict):
        self.batch = batch

    def __len__(self) -> int:
        return len(self.batch["task"])

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        if not -len(self) <= i < len(self):
            raise IndexError(i)
        return GatheredRow({k: v[i] for k, v in self.batch.items()})


class GatheredRow(dict):
    """One item of a `GatheredItems` (a plain dict of views; its own type so that `default_collate`
    dispatches a `GatheredItems` to `collate_gathered_items`)."""


def collate_gathered_items(batch, *, collate_fn_map=None):
    """torch `default_collate` for a sequence of `GatheredRow`s: a `GatheredItems` is already collated; a
    list of rows someone assembled is collated as plain dicts."""
    if isinstance(batch, GatheredItems):
        return batch.batch
    return collate([dict(row) for row in batch], collate_fn_map=collate_fn_map)


def register_gathered_collate() -> None:
    """Teach torch's `default_collate` (in this process) that a `GatheredItems` is collated already."""
    default_collate_fn_map[GatheredRow] = collate_gathered_items


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

    register_gathered_collate()  # here, so that spawned DataLoader workers (which unpickle the class) have it

    class InMemoryLeRobotDataset(LeRobotDataset):

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            use_in_memory_reader(self)

        def __getitems__(self, indices: list[int]) -> GatheredItems | list[dict]:
            """A DataLoader batch in one gather, already collated (torch's fetcher calls this instead of
            `__getitem__` per index, then the collate function): on the training device where the rule of
            "Device-resident batches" holds (`InMemoryReader.batch_device`), else on the CPU."""
            reader = self.reader
            if isinstance(reader, InMemoryReader) and (self.writer is None or dataset_is_finalized(self)):
                return GatheredItems(reader.get_batch(indices, reader.batch_device()))
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
