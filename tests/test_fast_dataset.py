"""The in-memory data path (`lerobot_bavo.datasets.fast`) returns exactly LeRobot's items, and only takes over
the datasets it can serve (training views without video)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.datasets.collect import CollectConfig, collect

SETTINGS = S.ObservationSettings(image_height=48, image_width=64, n_points=32)
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
