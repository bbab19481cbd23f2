"""The in-memory data path (`lerobot_bavo.datasets.fast`) returns exactly LeRobot's items, and only takes over
the datasets it can serve (training views without video)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from _helpers import SMALL_SETTINGS

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect import CollectConfig, collect

SETTINGS = SMALL_SETTINGS
STEPS = 30
REPO = "tester/bavo_fast"
FPS = 25
# ManiFlow / A-FAR windows: 2 observation steps (t-1, t), 16 actions from t-1 (LeRobot's delta_timestamps).
OBS_DELTA = [-1 / FPS, 0.0]
ACTION_DELTA = [i / FPS for i in range(-1, 15)]


@pytest.fixture(scope="module")
def views(tmp_path_factory) -> dict[str, Path]:
    """A 2-episode Stage dataset (seeds 0, 1) and its `points` and `state` views."""
    from lerobot_bavo.datasets.views import make_view

    root = tmp_path_factory.mktemp("fast") / "bavo_fast"
    collect(
        CollectConfig(
            task="cube_handoff",
            condition="stage",
            episodes=2,
            repo_id=REPO,
            root=root,
            workers=0,
            commit_every=1,
            settings=SETTINGS,
            episode_length=STEPS,
            progress=False,
            keep_failures=True,
        )
    )
    out = {"full": root}
    for view in ("points", "state"):
        out[view] = root.with_name(f"bavo_fast_{view}")
        make_view(root, view, output_root=out[view])
    return out


def _delta(features: dict) -> dict[str, list[float]]:
    d = {k: OBS_DELTA for k in features if k.startswith("observation.")}
    d[S.ACTION] = ACTION_DELTA
    return d


def _assert_same_item(a: dict, b: dict, where: str) -> None:
    assert list(a) == list(b), f"{where}: keys differ: {list(a)} vs {list(b)}"
    for key, va in a.items():
        vb = b[key]
        if isinstance(va, str):
            assert va == vb, f"{where}: {key}"
            continue
        assert va.dtype == vb.dtype and va.shape == vb.shape, (
            f"{where}: {key} {va.dtype}{tuple(va.shape)} vs {vb.dtype}{tuple(vb.shape)}"
        )
        assert torch.equal(va, vb), f"{where}: {key} values differ"


@pytest.mark.parametrize("view", ["points", "state"])
@pytest.mark.parametrize("with_delta", [True, False], ids=["delta_timestamps", "single_frame"])
def test_in_memory_items_equal_lerobot_items(views, view, with_delta):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_bavo.datasets.fast import InMemoryReader, use_in_memory_reader

    repo, root = f"{REPO}_{view}", views[view]
    probe = LeRobotDataset(repo, root=root)
    delta = _delta(probe.meta.features) if with_delta else None
    ref = LeRobotDataset(repo, root=root, delta_timestamps=delta)
    fast = LeRobotDataset(repo, root=root, delta_timestamps=delta)
    assert use_in_memory_reader(fast) and isinstance(fast.reader, InMemoryReader)
    # every frame: episode starts (padded past), ends (padded future actions) and the middle
    for i in range(len(ref)):
        _assert_same_item(ref[i], fast[i], f"{view} item {i}")
    assert len(fast) == len(ref) == 2 * STEPS and fast.num_episodes == 2


def test_in_memory_items_equal_lerobot_items_on_an_episode_subset(views):
    """Episode-filtered datasets (lerobot-train's eval split) hold non-contiguous absolute indices."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_bavo.datasets.fast import use_in_memory_reader

    repo, root = f"{REPO}_points", views["points"]
    delta = _delta(LeRobotDataset(repo, root=root).meta.features)
    ref = LeRobotDataset(repo, root=root, episodes=[1], delta_timestamps=delta)
    fast = LeRobotDataset(repo, root=root, episodes=[1], delta_timestamps=delta)
    assert use_in_memory_reader(fast)
    for i in (0, 1, 7, STEPS - 2, STEPS - 1):
        _assert_same_item(ref[i], fast[i], f"episode 1 item {i}")


def test_hook_serves_views_not_video_datasets_and_honours_the_opt_out(views, monkeypatch):
    from lerobot.datasets import factory

    from lerobot_bavo.datasets import fast

    original = factory.LeRobotDataset
    monkeypatch.setattr(factory, "LeRobotDataset", original)  # restored after the test
    monkeypatch.setenv(fast.ENV_OPT_OUT, "0")
    assert not fast.install_lerobot_train_hook() and factory.LeRobotDataset is original
    monkeypatch.setenv(fast.ENV_OPT_OUT, "1")
    assert fast.install_lerobot_train_hook() and factory.LeRobotDataset is not original
    assert fast.install_lerobot_train_hook()  # idempotent
    hooked = factory.LeRobotDataset
    served = hooked(f"{REPO}_points", root=views["points"])
    assert isinstance(served.reader, fast.InMemoryReader)
    full = hooked(REPO, root=views["full"], video_backend="pyav")  # has the active-camera video
    assert not isinstance(full.reader, fast.InMemoryReader)
    assert "image/video" in fast.supports(full)
    _ = full[3][S.OBS_IMAGE]  # LeRobot's own reader still decodes it


# ---- whole batches (`__getitems__`), on the CPU and on the training device ---------------------------------

# episode starts (padded past observations) and ends (padded future actions) of both episodes, the middle,
# repeats, any order
BATCH_ROWS = [0, 1, STEPS - 1, STEPS, STEPS + 1, 2 * STEPS - 1, 12, 12, 2 * STEPS - 2, STEPS - 2, 40, 5]


def _assert_same_batch(a: dict, b: dict, where: str) -> None:
    """Same keys in the same order, tensors of the same dtype, shape and values (compared on the CPU), and
    the same lists of task strings."""
    assert list(a) == list(b), f"{where}: keys differ: {list(a)} vs {list(b)}"
    for key, va in a.items():
        vb = b[key]
        if not isinstance(va, torch.Tensor):
            assert va == vb, f"{where}: {key}"
            continue
        vb = vb.cpu()
        assert va.dtype == vb.dtype and va.shape == vb.shape, (
            f"{where}: {key} {va.dtype}{tuple(va.shape)} vs {vb.dtype}{tuple(vb.shape)}"
        )
        assert torch.equal(va, vb), f"{where}: {key} values differ"


def _hooked_and_reference(views, view: str, with_delta: bool, episodes=None):
    """LeRobot's own dataset and the plugin hook's (`InMemoryLeRobotDataset`), same arguments."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_bavo.datasets.fast import in_memory_dataset_class

    repo, root = f"{REPO}_{view}", views[view]
    delta = _delta(LeRobotDataset(repo, root=root).meta.features) if with_delta else None
    ref = LeRobotDataset(repo, root=root, delta_timestamps=delta, episodes=episodes)
    return ref, in_memory_dataset_class()(repo, root=root, delta_timestamps=delta, episodes=episodes)


def _loader_batch(dataset, rows: list[int], **kwargs) -> dict:
    """The one batch a DataLoader (torch's default collate, as lerobot-train's for these views) makes of
    `rows`."""
    from torch.utils.data import DataLoader

    return next(iter(DataLoader(dataset, batch_size=len(rows), sampler=rows, num_workers=0, **kwargs)))


@pytest.mark.parametrize("view", ["points", "state"])
@pytest.mark.parametrize("with_delta", [True, False], ids=["delta_timestamps", "single_frame"])
def test_a_dataloader_batch_equals_lerobots_items_collated_on_the_cpu(views, view, with_delta):
    from torch.utils.data import default_collate

    from lerobot_bavo.datasets.fast import GatheredItems

    ref, fast = _hooked_and_reference(views, view, with_delta)
    expected = default_collate([ref[i] for i in BATCH_ROWS])
    assert isinstance(fast.__getitems__(BATCH_ROWS), GatheredItems)
    got = _loader_batch(fast, BATCH_ROWS)
    assert type(got) is dict and all(v.device.type == "cpu" for v in got.values() if torch.is_tensor(v))
    _assert_same_batch(expected, got, f"{view} batch")
    if with_delta:  # the rows include padded windows at both ends, and unpadded ones
        pad = got[f"{S.ACTION}_is_pad"]
        assert pad[BATCH_ROWS.index(STEPS - 1)].sum() == 14 and not pad[BATCH_ROWS.index(12)].any()
        assert pad[BATCH_ROWS.index(STEPS)][0] and not pad[BATCH_ROWS.index(STEPS + 1)][0]
    # a list of rows assembled by hand still collates as plain items
    rows = fast.__getitems__(BATCH_ROWS)
    _assert_same_batch(expected, default_collate([rows[i] for i in range(len(rows))]), f"{view} rows")


def test_a_dataloader_batch_equals_lerobots_items_collated_on_an_episode_subset(views):
    from torch.utils.data import default_collate

    ref, fast = _hooked_and_reference(views, "points", True, episodes=[1])
    rows = [0, 1, 7, STEPS - 2, STEPS - 1, 3]
    _assert_same_batch(default_collate([ref[i] for i in rows]), _loader_batch(fast, rows), "episode 1 batch")


def test_batches_stay_on_the_cpu_where_device_residency_does_not_apply(views, monkeypatch, caplog):
    """The rule of "Device-resident batches" on a machine without a GPU: columns over the allowed share of
    the free device memory, or BAVO_DEVICE_BATCHES=0, or a CPU accelerator, gather on the CPU (said once)."""
    from lerobot_bavo.datasets import fast

    cuda = torch.device("cuda")
    monkeypatch.setattr(fast, "training_device", lambda: cuda)
    free = 200_000  # bytes
    monkeypatch.setattr(torch.cuda, "mem_get_info", lambda device=None: (free, 10**9))
    _, ds = _hooked_and_reference(views, "points", True)
    need = ds.reader.store.nbytes
    assert need > 0.25 * free
    with caplog.at_level("INFO", logger=fast.__name__):
        assert ds.reader.batch_device() == fast.CPU
        assert ds.reader.batch_device() == fast.CPU  # decided once
    assert [r.getMessage() for r in caplog.records if "not held" in r.getMessage()] == [
        f"BAVO device batches: {REPO}_points not held on cuda: its columns take {need / 1e6:.1f} MB, over "
        f"BAVO_DEVICE_BATCHES=0.25 of the 0.2 MB free; batches gathered on the CPU"
    ]
    assert type(_loader_batch(ds, BATCH_ROWS)) is dict

    monkeypatch.setenv(fast.ENV_DEVICE_BATCHES, "0")
    _, off = _hooked_and_reference(views, "points", True)
    with caplog.at_level("INFO", logger=fast.__name__):
        assert off.reader.batch_device() == fast.CPU
    assert any("device batches off" in r.getMessage() for r in caplog.records)

    monkeypatch.setattr(fast, "training_device", lambda: fast.CPU)
    monkeypatch.delenv(fast.ENV_DEVICE_BATCHES)
    _, cpu = _hooked_and_reference(views, "points", True)
    assert cpu.reader.batch_device() == fast.CPU


def test_device_batches_share_reads_the_environment(monkeypatch):
    from lerobot_bavo.datasets import fast

    monkeypatch.delenv(fast.ENV_DEVICE_BATCHES, raising=False)
    assert fast.device_batches_share() == fast.DEFAULT_DEVICE_SHARE
    for text, share in (("0", 0.0), ("off", 0.0), ("0.5", 0.5), ("1", 1.0)):
        monkeypatch.setenv(fast.ENV_DEVICE_BATCHES, text)
        assert fast.device_batches_share() == share
    for bad in ("2", "-0.1", "yes"):
        monkeypatch.setenv(fast.ENV_DEVICE_BATCHES, bad)
        with pytest.raises(ValueError, match=fast.ENV_DEVICE_BATCHES):
            fast.device_batches_share()


def test_a_device_batch_passes_the_pin_memory_step_and_accelerate_unchanged():
    """What lerobot-train's DataLoader (pin_memory=True on CUDA) and accelerate's prepared loader (moving each
    batch to the accelerator's device) do to a batch already on the device: nothing."""
    from accelerate.utils import send_to_device
    from torch.utils.data._utils.pin_memory import pin_memory  # what torch's single-process iterator calls

    from lerobot_bavo.datasets.fast import DeviceBatch

    x = torch.zeros(2)
    batch = DeviceBatch(x=x, task=["a", "b"])
    assert batch.pin_memory() is batch and pin_memory(batch) is batch
    moved = send_to_device(batch, x.device)
    assert isinstance(moved, DeviceBatch) and moved["x"] is x and moved["task"] == ["a", "b"]


def test_the_device_gather_runs_off_the_cpu(views):
    """The device branch of `get_batch` (columns copied over, indices sent, a `DeviceBatch` back) on torch's
    `meta` device, which any machine has: the same keys, shapes and dtypes as the CPU batch, every tensor on
    that device. (Values are compared on CUDA, below, where there is one.)"""
    from lerobot_bavo.datasets.fast import DeviceBatch

    _, ds = _hooked_and_reference(views, "points", True)
    cpu, meta = ds.reader.get_batch(BATCH_ROWS), ds.reader.get_batch(BATCH_ROWS, "meta")
    assert isinstance(meta, DeviceBatch) and list(meta) == list(cpu) and meta["task"] == cpu["task"]
    for key, value in cpu.items():
        if torch.is_tensor(value):
            assert meta[key].device.type == "meta", key
            assert (meta[key].shape, meta[key].dtype) == (value.shape, value.dtype), key
    assert ds.reader.hold_on("meta") is ds.reader.hold_on("meta")  # copied once


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("view", ["points", "state"])
@pytest.mark.parametrize("with_delta", [True, False], ids=["delta_timestamps", "single_frame"])
def test_a_batch_gathered_on_cuda_equals_lerobots_items_collated(views, view, with_delta, monkeypatch):
    """lerobot-train's loader on CUDA with --num_workers=0 (pin_memory=True): the batch comes out on the
    device, and is LeRobot's items collated, bit for bit."""
    import pickle

    from torch.utils.data import default_collate

    from lerobot_bavo.datasets import fast

    device = torch.device("cuda", torch.cuda.current_device())
    monkeypatch.setattr(fast, "training_device", lambda: device)
    ref, ds = _hooked_and_reference(views, view, with_delta)
    expected = default_collate([ref[i] for i in BATCH_ROWS])
    got = _loader_batch(ds, BATCH_ROWS, pin_memory=True)
    assert isinstance(got, fast.DeviceBatch) and ds.reader.batch_device() == device
    assert all(v.device == device for v in got.values() if torch.is_tensor(v))
    _assert_same_batch(expected, got, f"{view} CUDA batch")
    _assert_same_batch(expected, ds.reader.get_batch(BATCH_ROWS, device), f"{view} get_batch")
    # workers receive the reader without the device copy, and gather on the CPU
    state = pickle.loads(pickle.dumps(ds.reader)).__getstate__()
    assert state["_device_store"] is None and state["store"].device.type == "cpu"
    _assert_same_batch(expected, ds.reader.get_batch(BATCH_ROWS), f"{view} CPU batch")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_batch_gathered_on_cuda_equals_lerobots_items_collated_on_an_episode_subset(views):
    from torch.utils.data import default_collate

    ref, fast = _hooked_and_reference(views, "points", True, episodes=[1])
    rows = [0, 1, 7, STEPS - 2, STEPS - 1, 3]
    _assert_same_batch(default_collate([ref[i] for i in rows]), fast.reader.get_batch(rows, "cuda"),
                       "episode 1 CUDA batch")


def test_column_array_reads_fixed_and_variable_size_lists_alike():
    """LeRobot's `merge_datasets` writes list columns as variable-size `list<float>`: they read as the same
    array as the fixed-size lists of a collection (slices included); lists of different
    lengths are refused."""
    import numpy as np
    import pyarrow as pa

    from lerobot_bavo.datasets.fast import column_array

    rows = np.arange(12, dtype=np.float32).reshape(4, 3)
    fixed = pa.array(rows.tolist(), type=pa.list_(pa.float32(), 3))
    variable = pa.array(rows.tolist(), type=pa.list_(pa.float32()))
    np.testing.assert_array_equal(column_array(fixed), rows)
    np.testing.assert_array_equal(column_array(variable), rows)
    chunked = pa.chunked_array([variable.slice(0, 1), variable.slice(1)])
    np.testing.assert_array_equal(column_array(chunked), rows)
    np.testing.assert_array_equal(column_array(variable.slice(2)), rows[2:])
    nested = pa.array([[[1.0, 2.0]], [[3.0, 4.0]]], type=pa.list_(pa.list_(pa.float64())))
    np.testing.assert_array_equal(column_array(nested), [[[1.0, 2.0]], [[3.0, 4.0]]])
    with pytest.raises(ValueError, match="differ in length"):
        column_array(pa.array([[1.0], [2.0, 3.0]], type=pa.list_(pa.float32())))
