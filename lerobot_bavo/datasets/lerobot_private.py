"""Every use of LeRobot 0.6.1's private internals, in one place (datasets, config loading, policies).

Why they are needed: `bavo-collect` appends episodes through LeRobot's public writer API
(`LeRobotDataset.create / resume`, `add_frame`, `save_episode`, `finalize`). What that API does not
offer:

1. Abandoning a writer after an error. The collector rolls an interrupted commit back from its
   snapshot; LeRobot's `__del__` safety nets would otherwise flush buffered episode metadata into
   files the rollback just deleted. `abandon_writer` disarms them (`_pq_writer`, `_finalized`,
   `_metadata_buffer`, `_is_finalized`).
2. Skipping a no-op pass. `DatasetWriter._save_episode_data` calls `io_utils.embed_images`, a
   row-by-row `datasets.map`, on every episode. With images stored as video no column needs
   embedding and the pass returns the table unchanged, yet it costs about half of the writer's time
   (docs/results/costs.md, as for items 3-5). `skip_noop_image_embedding` replaces the module attribute in
   exactly that case.
3. Cheaper episode statistics. `DatasetWriter.save_episode` calls `compute_stats.compute_episode_stats`,
   which builds a 5000-bin histogram per dimension of every numeric feature (a large share of the
   writer's CPU for BAVO's wide features). `exact_fast_episode_stats` swaps in `datasets.episode_stats`, which
   gives the same statistics bit for bit (tested against LeRobot's function) without the histograms.
4. Cheaper streaming image statistics. LeRobot's video encoder thread updates a
   `compute_stats.RunningQuantileStats` with every frame (a float32 reduction and histograms per
   frame). `deferred_video_frame_stats` swaps in `datasets.video_stats.DeferredFrameStats`, which
   replays the same updates once per episode, bit for bit (a subclass of `datasets.quantile_stats`'
   copy of LeRobot's class, tested against LeRobot's).
5. A cheaper episode table. `DatasetWriter._save_episode_data` builds each episode's table with
   `datasets.Dataset.from_dict` (mostly Python work per column and feature bookkeeping) and writes
   `with_format("arrow")[:]` of it. `arrow_episode_tables` gives LeRobot's writer module a `datasets` whose
   `Dataset.from_dict` builds the same Arrow table directly from the numpy columns (an order of magnitude
   faster) when every column is a plain number or a fixed-length list of numbers with exactly the feature's
   dtype, and calls the real `from_dict` otherwise; the written parquet files are the same bytes (tested).
   It hands LeRobot an `_EpisodeTable`, not a `datasets.Dataset`: the three things the writer uses of it
   (`features`, `len`, `with_format("arrow")[:]`); building a real one cost as much again (its fingerprint,
   a hash of the whole object, its feature bookkeeping and a deep copy per `with_format`). Only LeRobot's
   `embed_images` pass would use more (it would write the fingerprint into the file), and that pass is
   skipped within the block (item 2; it is a no-op whenever the shortcut applies).

6. Loading a policy config without litter. `PreTrainedConfig.from_pretrained` copies config.json into a
   `tempfile.NamedTemporaryFile(delete=False)` for draccus and never removes it: every checkpoint load left a
   `tmpXXXX.json` in the temp folder. `config_tempfiles_removed` gives LeRobot's config module a `tempfile`
   whose temporary files go to a private folder, deleted when the block ends.
7. The fast data path (`datasets.fast`): a `DatasetReader`'s metadata (`_meta`) and image transforms
   (`_image_transforms`), a dataset's `_is_finalized`, and the dataset factory's module global
   `LeRobotDataset`, which `install_dataset_class` replaces (`reader_metadata`, `reader_image_transforms`,
   `dataset_is_finalized`).
8. A chunking policy's queue of actions still to execute (`_queues["action"]`, ACT's `_action_queue`),
   which `bavo-eval --rerun` records (`policy_action_queue`).
9. Episodes whose video was encoded where they were recorded (issue 30: a `bavo-collect` worker encodes
   the active camera's mp4 exactly as LeRobot's streaming encoder would, `datasets.episode_payload`).
   LeRobot's writer takes an episode's mp4 and frame statistics only from its streaming encoder
   (`DatasetWriter._streaming_encoder.finish_episode()`); `prebuilt_episode_videos` puts a `PrebuiltVideos`
   there, which hands over the worker's, so LeRobot still places the mp4 and records it as its own.
   `memoized_task_index` answers LeRobot's per-frame task-index lookups (a pandas `loc` each) from memory.
   `deferred_stats_writes` keeps the dataset statistics LeRobot's metadata rewrites to `meta/stats.json`
   after every episode (`dataset_metadata.write_stats`) until the session's end: the same last file.

`check_private_api()` names every field and attribute used here; a test calls it, so an upgrade of
LeRobot that renames one fails there with a message saying which, not deep inside a collection.
"""

from __future__ import annotations

import contextlib

# (what, where): the private names this module touches.
WRITER_FIELDS = ("_pq_writer", "_finalized", "_streaming_encoder")
META_FIELDS = ("_metadata_buffer", "_pq_writer", "_finalized")
DATASET_FIELDS = ("_is_finalized",)
READER_FIELDS = ("_meta", "_image_transforms")  # DatasetReader internals the fast data path reads
CONFIG_MODULE_ATTRIBUTES = ("tempfile",)  # lerobot.configs.policies
FACTORY_MODULE_ATTRIBUTES = ("LeRobotDataset",)  # lerobot.datasets.factory
WRITER_MODULE_ATTRIBUTES = ("embed_images", "compute_episode_stats", "datasets")
METADATA_MODULE_ATTRIBUTES = ("write_stats",)  # lerobot.datasets.dataset_metadata
# lerobot.datasets.compute_stats, read by the encoder thread
STATS_MODULE_ATTRIBUTES = ("RunningQuantileStats",)


class LeRobotInternalsChanged(RuntimeError):
    """The installed LeRobot lacks a private name lerobot-bavo relies on."""


def check_private_api(dataset=None) -> None:
    """Raise `LeRobotInternalsChanged` naming each missing private name.

    Module attributes are always checked; instance fields only when a `LeRobotDataset` writer session
    (`dataset`, from `create` or `resume`) is given, since they exist only on instances.
    """
    import lerobot
    import lerobot.configs.policies as config_mod
    import lerobot.datasets.compute_stats as stats_mod
    import lerobot.datasets.dataset_metadata as meta_mod
    import lerobot.datasets.dataset_writer as writer_mod
    import lerobot.datasets.factory as factory_mod

    missing = [
        f"lerobot.datasets.dataset_writer.{a}" for a in WRITER_MODULE_ATTRIBUTES if not hasattr(writer_mod, a)
    ]
    missing += [
        f"lerobot.configs.policies.{a}" for a in CONFIG_MODULE_ATTRIBUTES if not hasattr(config_mod, a)
    ]
    missing += [f"lerobot.datasets.dataset_metadata.{a}" for a in METADATA_MODULE_ATTRIBUTES
                if not hasattr(meta_mod, a)]
    missing += [
        f"lerobot.datasets.factory.{a}" for a in FACTORY_MODULE_ATTRIBUTES if not hasattr(factory_mod, a)
    ]
    missing += [
        f"lerobot.datasets.compute_stats.{a}" for a in STATS_MODULE_ATTRIBUTES if not hasattr(stats_mod, a)
    ]
    if dataset is not None:
        writer, meta = getattr(dataset, "writer", None), getattr(dataset, "meta", None)
        if writer is None:
            missing.append("LeRobotDataset.writer")
        else:
            missing += [f"DatasetWriter.{f}" for f in WRITER_FIELDS if not hasattr(writer, f)]
            if not hasattr(writer, "cancel_pending_videos"):
                missing.append("DatasetWriter.cancel_pending_videos")
        missing += [
            f"LeRobotDatasetMetadata.{f}" for f in META_FIELDS if meta is None or not hasattr(meta, f)
        ]
        missing += [f"LeRobotDataset.{f}" for f in DATASET_FIELDS if not hasattr(dataset, f)]
        reader = getattr(dataset, "reader", None)
        if reader is not None:  # a writer session may have no reader yet
            missing += [f"DatasetReader.{f}" for f in READER_FIELDS if not hasattr(reader, f)]
    if missing:
        raise LeRobotInternalsChanged(
            f"LeRobot {getattr(lerobot, '__version__', '?')} lacks {', '.join(missing)}, which "
            "lerobot_bavo/datasets/lerobot_private.py uses (tested with lerobot 0.6.1); adapt that module")


def abandon_writer(ds) -> None:
    """Drop a LeRobot writer session after an error without letting its finalizers write anything more."""
    writer, meta = getattr(ds, "writer", None), getattr(ds, "meta", None)
    try:
        if writer is not None:
            writer.cancel_pending_videos()
            writer._pq_writer = None
            writer._finalized = True
        if meta is not None:
            meta._metadata_buffer = []
            meta._pq_writer = None
            meta._finalized = True
        ds._is_finalized = True
    except Exception:  # best effort: the rollback that follows restores the files anyway
        pass


@contextlib.contextmanager
def skip_noop_image_embedding():
    """Within the block, LeRobot's per-episode `embed_images` returns the table unchanged when no
    column holds embeddable images (the only case it would be a no-op), and runs as usual otherwise."""
    import lerobot.datasets.dataset_writer as writer_mod
    from datasets.features.features import require_storage_embed

    original = writer_mod.embed_images

    def embed_images(dataset):
        if any(require_storage_embed(f) for f in dataset.features.values()):
            return original(dataset)
        return dataset

    writer_mod.embed_images = embed_images
    try:
        yield
    finally:
        writer_mod.embed_images = original


@contextlib.contextmanager
def exact_fast_episode_stats(known: dict | None = None):
    """Within the block, LeRobot's writer computes per-episode statistics with
    `lerobot_bavo.datasets.episode_stats.compute_episode_stats` (equal to LeRobot's, without per-dimension
    histograms), taking the statistics in `known` (feature -> statistics; the caller fills it before each
    `save_episode`, e.g. with a worker's) as they are."""
    import functools

    import lerobot.datasets.dataset_writer as writer_mod

    from lerobot_bavo.datasets.episode_stats import compute_episode_stats

    original = writer_mod.compute_episode_stats
    writer_mod.compute_episode_stats = functools.partial(compute_episode_stats, known=known)
    try:
        yield
    finally:
        writer_mod.compute_episode_stats = original


@contextlib.contextmanager
def deferred_video_frame_stats():
    """Within the block, LeRobot's streaming video encoder threads compute their image statistics with
    `lerobot_bavo.datasets.video_stats.DeferredFrameStats` (equal to LeRobot's, computed once per episode).

    The thread looks `RunningQuantileStats` up in `lerobot.datasets.compute_stats` when it starts, so threads
    started inside the block use the replacement; it falls back to LeRobot's own updates for anything that
    is not a uint8 frame, so other users of the class in the block get unchanged results too."""
    import lerobot.datasets.compute_stats as stats_mod

    from lerobot_bavo.datasets.video_stats import DeferredFrameStats

    original = stats_mod.RunningQuantileStats
    stats_mod.RunningQuantileStats = DeferredFrameStats
    try:
        yield
    finally:
        stats_mod.RunningQuantileStats = original


class PrebuiltVideos:
    """Stands in for a writer's `StreamingVideoEncoder` when every episode's video was encoded elsewhere (a
    `bavo-collect` worker, `episode_payload`): `finish_episode` hands LeRobot's `save_episode` the mp4 and raw
    frame statistics set by `put`, as the streaming encoder would hand over its own."""

    def __init__(self):
        self._next: dict | None = None

    def put(self, videos: dict) -> None:
        """The next episode's {video_key: (mp4 path in a folder of its own, raw statistics or None)}; LeRobot
        moves or appends the mp4 into the dataset and deletes its folder."""
        self._next = videos

    def start_episode(self, *args, **kwargs) -> None:  # noqa: ARG002 (the encoder's interface)
        raise RuntimeError("PrebuiltVideos takes encoded episodes only (save_episode with episode_data)")

    feed_frame = start_episode

    def finish_episode(self) -> dict:
        if self._next is None:
            raise RuntimeError("save_episode without a prebuilt video (PrebuiltVideos.put was not called)")
        videos, self._next = self._next, None
        return videos

    def cancel_episode(self) -> None:
        self._next = None

    def close(self) -> None:
        self._next = None


@contextlib.contextmanager
def prebuilt_episode_videos(dataset):
    """Within the block, `dataset`'s writer takes each episode's video from the `PrebuiltVideos` yielded
    (`put` before every `save_episode(episode_data=...)`) instead of encoding frames: the writer's private
    `_streaming_encoder` is replaced, and restored afterwards (so an episode fed frame by frame after the
    block, e.g. one staged without a video, is encoded by LeRobot as usual)."""
    writer = dataset.writer
    original = writer._streaming_encoder
    videos = PrebuiltVideos()
    writer._streaming_encoder = videos
    try:
        yield videos
    finally:
        writer._streaming_encoder = original


@contextlib.contextmanager
def memoized_task_index(dataset):
    """Within the block, `dataset.meta.get_task_index` answers a task it has answered before from memory.
    LeRobot's `save_episode` looks the task of every frame up in a pandas table (`tasks.loc[task]`), hundreds
    of lookups of one description per episode; a task's index never changes once it exists (tasks are only
    added), and an unknown task (None) is not remembered. The instance attribute is removed afterwards."""
    meta = dataset.meta
    lookup = meta.get_task_index
    known: dict[str, int] = {}

    def get_task_index(task: str) -> int | None:
        if task not in known:
            index = lookup(task)
            if index is None:
                return None
            known[task] = index
        return known[task]

    meta.get_task_index = get_task_index
    try:
        yield
    finally:
        del meta.get_task_index


class DeferredStatsWrite:
    """The last `meta/stats.json` a writer session asked for, written by `flush` (see
    `deferred_stats_writes`)."""

    def __init__(self, write):
        self._write = write
        self._last: tuple | None = None

    def __call__(self, stats, root) -> None:
        self._last = (stats, root)

    def flush(self) -> None:
        if self._last is not None:
            self._write(*self._last)
            self._last = None


@contextlib.contextmanager
def deferred_stats_writes():
    """Within the block, LeRobot's metadata keeps the dataset statistics it aggregates after every episode in
    memory instead of rewriting `meta/stats.json` each time (a JSON dump of every feature's statistics, a
    large share of the writer's remaining per-episode CPU, issue 30); `flush()` on the object yielded writes
    the last one (call it before the session's commit point). Not flushed, nothing is written: an abandoned
    session's statistics are restored from its snapshot anyway. Replaces `dataset_metadata.write_stats`."""
    import lerobot.datasets.dataset_metadata as meta_mod

    original = meta_mod.write_stats
    deferred = DeferredStatsWrite(original)
    meta_mod.write_stats = deferred
    try:
        yield deferred
    finally:
        meta_mod.write_stats = original


class _EpisodeTable:
    """What LeRobot's `_save_episode_data` uses of the `datasets.Dataset` it builds per episode, for a table
    built directly in Arrow: `features` (read by the image-embedding pass, skipped within
    `arrow_episode_tables`), `len()`, and `with_format("arrow")[:]`, the table it writes. A real
    `datasets.Dataset` costs more to construct than the table (its feature bookkeeping, a deep copy per
    `with_format`) and would only be thrown away."""

    def __init__(self, table, features):
        self.table, self.features = table, features

    def __len__(self) -> int:
        return self.table.num_rows

    def with_format(self, type=None, **kwargs):  # noqa: A002 (datasets' signature)
        if type != "arrow" or kwargs:
            raise NotImplementedError(f"an episode table built in Arrow offers only with_format('arrow'), "
                                      f"not {type!r} {kwargs}")
        return self

    def __getitem__(self, key):
        if key != slice(None):
            raise NotImplementedError(f"an episode table built in Arrow offers only [:], not [{key!r}]")
        return self.table


class _ArrowDataset:
    """`datasets.Dataset` as LeRobot's writer module sees it inside `arrow_episode_tables`: `from_dict` builds
    the Arrow table directly where that gives exactly `datasets`' table (see `arrow_table_of`), as an
    `_EpisodeTable`, and calls `datasets.Dataset.from_dict` otherwise."""

    @staticmethod
    def from_dict(mapping, features=None, info=None, split=None):
        import datasets

        table = arrow_table_of(mapping, features) if info is None else None
        if table is None:
            return datasets.Dataset.from_dict(mapping, features=features, info=info, split=split)
        return _EpisodeTable(table, features)

    def __getattr__(self, name):  # pragma: no cover - LeRobot's writer uses only from_dict
        import datasets

        return getattr(datasets.Dataset, name)


def arrow_table_of(mapping: dict, features):
    """The Arrow table `datasets.Dataset.from_dict(mapping, features=features)` holds, built directly, or None
    where this shortcut does not apply: `features` must be a `datasets.Features` whose columns are all numeric
    `Value`s or fixed-length `List`s of numeric `Value`s (Arrow primitive or fixed_size_list types), named
    exactly by `mapping`, and each column a numpy array of the feature's dtype with n rows of that many values
    (or, for a plain float feature, of another float dtype, cast as `datasets` casts it):
    `lerobot_format.episode_table` on the features' Arrow schema.
    """
    import datasets

    from lerobot_bavo.datasets.lerobot_format import episode_table

    if not isinstance(features, datasets.Features):
        return None
    return episode_table(mapping, features.arrow_schema)


@contextlib.contextmanager
def arrow_episode_tables():
    """Within the block, LeRobot's writer builds episode tables with `_ArrowDataset.from_dict` (see item 5 of
    the module docstring); only the writer module's own reference to `datasets` is replaced."""
    import types

    import datasets
    import lerobot.datasets.dataset_writer as writer_mod

    original = writer_mod.datasets
    proxy = types.ModuleType("datasets")
    proxy.__dict__.update(datasets.__dict__)
    proxy.Dataset = _ArrowDataset()
    writer_mod.datasets = proxy
    try:
        # A table built here has another `datasets` fingerprint than `from_dict`'s; LeRobot's `embed_images`
        # pass would write it into the parquet metadata, so the pass must be skipped (it is a no-op whenever
        # this shortcut applies: numeric columns only).
        with skip_noop_image_embedding():
            yield
    finally:
        writer_mod.datasets = original


@contextlib.contextmanager
def config_tempfiles_removed():
    """Within the block, the temporary files LeRobot's `configs.policies` creates (one json per
    `PreTrainedConfig.from_pretrained`, never deleted) go to a private folder that is removed afterwards.
    Only that module's reference to `tempfile` is replaced, by a copy whose `NamedTemporaryFile` defaults
    `dir` to the folder."""
    import functools
    import shutil
    import tempfile
    import types

    import lerobot.configs.policies as config_mod

    folder = tempfile.mkdtemp(prefix="bavo-config-")
    original = config_mod.tempfile
    proxy = types.ModuleType("tempfile")
    proxy.__dict__.update(tempfile.__dict__)
    proxy.NamedTemporaryFile = functools.partial(tempfile.NamedTemporaryFile, dir=folder)
    config_mod.tempfile = proxy
    try:
        yield
    finally:
        config_mod.tempfile = original
        shutil.rmtree(folder, ignore_errors=True)


def reader_metadata(reader):
    """The `LeRobotDatasetMetadata` a `DatasetReader` reads episodes from (`reader._meta`)."""
    return reader._meta


def reader_image_transforms(reader):
    """A `DatasetReader`'s image transforms, or None (`reader._image_transforms`)."""
    return getattr(reader, "_image_transforms", None)


def dataset_is_finalized(dataset) -> bool:
    """Whether a `LeRobotDataset`'s writer session is finalized (`dataset._is_finalized`)."""
    return bool(dataset._is_finalized)


def install_dataset_class(cls) -> bool:
    """Make LeRobot's dataset factory (`lerobot-train`) build `cls` wherever it builds a `LeRobotDataset`: the
    factory looks the class up as its module global, replaced here (and only here). Idempotent: returns False
    when `cls` is already installed."""
    from lerobot.datasets import factory

    if factory.LeRobotDataset is cls:
        return False
    factory.LeRobotDataset = cls
    return True


def policy_action_queue(policy):
    """The policy's queue of actions still to execute from its last chunk (LeRobot's `_queues["action"]` or
    ACT's `_action_queue`), or None."""
    queues = getattr(policy, "_queues", None)
    if isinstance(queues, dict) and "action" in queues:
        return queues["action"]
    return getattr(policy, "_action_queue", None)
