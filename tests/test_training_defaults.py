"""`lerobot-train` with LeRobot's own defaults (4 `spawn` DataLoader workers), on a BAVO training view and on
a dataset of another robot; the batched in-memory data path gives LeRobot's items whatever the worker
count."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from _helpers import lerobot_cli, run_offline, tiny_points_view

from lerobot_bavo.datasets import schema as S

SETTINGS = S.ObservationSettings(image_height=48, image_width=64, n_points=32)
FPS = 25
OBS_DELTA = [-1 / FPS, 0.0]
ACTION_DELTA = [i / FPS for i in range(-1, 15)]


def _train(args: list[str], tmp_path: Path):
    return run_offline(lerobot_cli("lerobot-train", "lerobot.scripts.lerobot_train") + args, tmp_path)


@pytest.fixture(scope="module")
def points_view(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("defaults") / "bavo_defaults"
    return tiny_points_view(root, "tester/bavo_defaults", SETTINGS)


@pytest.fixture(scope="module")
def other_robot_dataset(tmp_path_factory) -> Path:
    """A LeRobot dataset of another robot: 6-dim state and action (no BAVO names), a 16-point cloud."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    root = tmp_path_factory.mktemp("other") / "arm6"
    n = 16
    features = {
        "observation.state": {"dtype": "float32", "shape": (6,), "names": [f"j{i}" for i in range(6)]},
        "action": {"dtype": "float32", "shape": (6,), "names": [f"j{i}" for i in range(6)]},
        "observation.point_cloud": {"dtype": "float32", "shape": (n * 6,), "names": None},
    }
    ds = LeRobotDataset.create("tester/arm6", fps=FPS, root=root, features=features, use_videos=False)
    rng = np.random.default_rng(0)
    for _ in range(2):
        for _ in range(30):
            ds.add_frame({"observation.state": rng.standard_normal(6).astype(np.float32),
                          "action": rng.standard_normal(6).astype(np.float32),
                          "observation.point_cloud": rng.random(n * 6).astype(np.float32), "task": "reach"})
        ds.save_episode()
    ds.finalize()
    return root


def test_lerobot_defaults_train_afar_on_a_bavo_view(points_view, tmp_path):
    """No --num_workers: LeRobot's 4 `spawn` workers receive the in-memory dataset (they used to fail to
    pickle it), and the occluder-dropout recipe reads the view's per-point label."""
    out = tmp_path / "run"
    proc = _train(
        [
            "--policy.type=afar",
            "--policy.preset=cpu_fast",
            "--policy.points_per_step=16",
            "--policy.device=cpu",
            "--policy.occluder_dropout=0.5",
            "--dataset.repo_id=tester/bavo_defaults_points",
            f"--dataset.root={points_view}",
            "--batch_size=4",
            "--steps=2",
            "--save_freq=2",
            "--log_freq=1",
            f"--output_dir={out}",
            "--wandb.enable=false",
        ],
        tmp_path,
    )
    assert "loss_evo" in proc.stdout + proc.stderr
    cfg = json.loads((out / "checkpoints" / "last" / "pretrained_model" / "config.json").read_text())
    assert cfg["binary_action_dims"] == [6, 13]  # BAVO's gripper commands, found by the action's names
    train_cfg = json.loads(
        (out / "checkpoints" / "last" / "pretrained_model" / "train_config.json").read_text()
    )
    assert train_cfg["num_workers"] == 4


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_lerobot_train_on_cuda_without_workers_gathers_batches_on_the_device(points_view, tmp_path):
    """--num_workers=0 on CUDA: the view is held on the GPU and batches are gathered there (one log line says
    so, with the memory it takes); the batch goes through LeRobot's pinning, accelerate and preprocessor."""
    proc = _train(
        [
            "--policy.type=afar",
            "--policy.preset=cpu_fast",
            "--policy.points_per_step=16",
            "--policy.device=cuda",
            "--policy.push_to_hub=false",
            "--dataset.repo_id=tester/bavo_defaults_points",
            f"--dataset.root={points_view}",
            "--num_workers=0",
            "--batch_size=8",
            "--steps=3",
            "--log_freq=1",
            "--save_checkpoint=false",
            f"--output_dir={tmp_path / 'run'}",
            "--wandb.enable=false",
        ],
        tmp_path,
    )
    log = proc.stdout + proc.stderr
    assert "BAVO device batches: tester/bavo_defaults_points held on cuda" in log, log[-3000:]
    assert "step:3" in log


def test_lerobot_defaults_train_maniflow_on_another_robots_dataset(other_robot_dataset, tmp_path):
    """A 6-dim action with other names: nothing is snapped, and the policy trains, saves and loads."""
    out = tmp_path / "run"
    _train(
        [
            "--policy.type=maniflow",
            "--policy.preset=cpu_fast",
            "--policy.points_per_step=8",
            "--policy.device=cpu",
            "--dataset.repo_id=tester/arm6",
            f"--dataset.root={other_robot_dataset}",
            "--batch_size=4",
            "--steps=2",
            "--save_freq=2",
            "--log_freq=1",
            f"--output_dir={out}",
            "--wandb.enable=false",
        ],
        tmp_path,
    )
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    cfg = json.loads((ckpt / "config.json").read_text())
    assert cfg["binary_action_dims"] == []

    from lerobot_bavo.policies import ManiFlowPolicy

    policy = ManiFlowPolicy.from_pretrained(ckpt).eval()
    obs = {"observation.point_cloud": torch.rand(1, 16, 6), "observation.state": torch.rand(1, 6)}
    assert policy.select_action(obs).shape == (1, 6)


def _datasets(root: Path, repo: str):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    from lerobot_bavo.datasets.fast import in_memory_dataset_class

    features = LeRobotDataset(repo, root=root).meta.features
    delta = {k: OBS_DELTA for k in features if k.startswith("observation.")}
    delta[S.ACTION] = ACTION_DELTA
    return (LeRobotDataset(repo, root=root, delta_timestamps=delta),
            in_memory_dataset_class()(repo, root=root, delta_timestamps=delta))


def _assert_same_batch(a: dict, b: dict) -> None:
    assert list(a) == list(b)
    for key in a:
        if isinstance(a[key], torch.Tensor):
            assert a[key].dtype == b[key].dtype and torch.equal(a[key], b[key]), key
        else:
            assert a[key] == b[key], key


def test_a_batch_gathered_at_once_equals_lerobots_items_collated(points_view):
    from torch.utils.data import default_collate

    ref, fast = _datasets(points_view, "tester/bavo_defaults_points")
    # episode starts and ends (padded windows), both episodes, repeats, any order
    indices = [0, 1, 39, 40, 41, 79, 12, 12, 60]
    _assert_same_batch(
        default_collate([ref[i] for i in indices]), default_collate(fast.__getitems__(indices))
    )


@pytest.mark.parametrize("workers", [2])
def test_dataloader_workers_give_the_same_first_batch(points_view, workers):
    from torch.utils.data import DataLoader

    _, fast = _datasets(points_view, "tester/bavo_defaults_points")

    def first(num_workers: int) -> dict:
        loader = DataLoader(fast, batch_size=8, shuffle=True, num_workers=num_workers,
                            generator=torch.Generator().manual_seed(0),
                            multiprocessing_context="spawn" if num_workers else None)
        return next(iter(loader))

    _assert_same_batch(first(0), first(workers))
