"""`lerobot-train --policy.type=afar` on a real (tiny) BAVO dataset: checkpoints, resume, and both
evaluators loading the result. Runs LeRobot's own CLIs in subprocesses, as a user would (~1 min)."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from _helpers import lerobot_cli, run_offline, tiny_points_view

from lerobot_bavo.datasets import schema as S
from lerobot_bavo.features import TEACHER_PREFIX

SETTINGS = S.ObservationSettings(image_height=48, image_width=64, n_points=32)




@pytest.fixture(scope="module")
def points_dataset(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("train") / "bavo_tiny"
    return tiny_points_view(root, "tester/bavo_tiny", SETTINGS)


def test_afar_trains_checkpoints_resumes_and_evaluates(points_dataset, tmp_path):
    out = tmp_path / "run"
    train = lerobot_cli("lerobot-train", "lerobot.scripts.lerobot_train") + [
        "--policy.type=afar", "--policy.preset=cpu", "--policy.device=cpu", "--policy.push_to_hub=false",
        "--policy.scheduler_warmup_steps=1", "--dataset.repo_id=tester/bavo_tiny_points",
        f"--dataset.root={points_dataset}", "--num_workers=0", "--batch_size=4", "--steps=2", "--save_freq=2",
        "--log_freq=1", f"--output_dir={out}", "--wandb.enable=false", "--seed=3",
    ]
    first = run_offline(train, tmp_path)
    assert "loss_evo" in first.stdout + first.stderr  # A-FAR's relational terms are logged
    ckpt2 = out / "checkpoints" / "000002"
    assert (ckpt2 / "pretrained_model" / "model.safetensors").is_file()

    # Resume from the saved training state to step 4 (LeRobot's documented resume flags).
    resume = lerobot_cli("lerobot-train", "lerobot.scripts.lerobot_train") + [
        f"--config_path={ckpt2 / 'pretrained_model' / 'train_config.json'}", "--resume=true", "--steps=4",
        "--save_freq=2"]
    run_offline(resume, tmp_path)
    state = json.loads((out / "checkpoints" / "000004" / "training_state" / "training_step.json").read_text())
    assert state["step"] == 4
    ckpt = out / "checkpoints" / "last" / "pretrained_model"
    cfg = json.loads((ckpt / "config.json").read_text())
    assert cfg["type"] == "afar" and not any(k.startswith(TEACHER_PREFIX) for k in cfg["input_features"])

    # bavo-eval loads it (no teacher keys at evaluation) and finishes an episode.
    from lerobot_bavo.envs.bavo_env import BavoEnv
    from lerobot_bavo.eval.rollout import LeRobotPolicyAgent

    env = BavoEnv("cube_handoff", "clean", image_height=48, image_width=64, n_points=32, episode_length=12)
    try:
        agent = LeRobotPolicyAgent(ckpt, env)
        obs, info = env.reset(seed=0)
        agent.reset()
        for _ in range(12):
            action = agent.act(obs, info)
            assert action.shape == (21,) and np.isfinite(action).all()
            obs, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
    finally:
        env.close()

    # lerobot-eval loads it too.
    eval_out = tmp_path / "eval"
    run_offline(
        lerobot_cli("lerobot-eval", "lerobot.scripts.lerobot_eval")
        + [
            f"--policy.path={ckpt}",
            "--policy.device=cpu",
            "--env.type=bavo",
            "--env.task=cube_handoff",
            "--env.episode_length=10",
            "--env.image_height=48",
            "--env.image_width=64",
            "--env.n_points=32",
            "--eval.n_episodes=1",
            "--eval.batch_size=1",
            "--eval.use_async_envs=false",
            f"--output_dir={eval_out}",
        ],
        tmp_path,
    )
    assert json.loads((eval_out / "eval_info.json").read_text())["overall"]["n_episodes"] == 1


def test_afar_trains_with_lerobot_use_amp(points_dataset, tmp_path):
    """`--policy.use_amp=true`: lerobot-train runs the step under bf16 autocast (the config's `dtype`; on the
    CPU as on CUDA) and the relational terms stay finite (they compute distances in fp32)."""
    out = tmp_path / "run"
    proc = run_offline(
        lerobot_cli("lerobot-train", "lerobot.scripts.lerobot_train")
        + [
            "--policy.type=afar",
            "--policy.preset=cpu_fast",
            "--policy.points_per_step=32",
            "--policy.device=cpu",
            "--policy.push_to_hub=false",
            "--policy.use_amp=true",
            "--policy.scheduler_warmup_steps=1",
            "--dataset.repo_id=tester/bavo_tiny_points",
            f"--dataset.root={points_dataset}",
            "--num_workers=0",
            "--batch_size=4",
            "--steps=2",
            "--save_freq=2",
            "--log_freq=1",
            f"--output_dir={out}",
            "--wandb.enable=false",
            "--seed=3",
        ],
        tmp_path,
    )
    losses = re.findall(r"\bloss_evo:(\S+)", proc.stdout + proc.stderr)
    assert len(losses) == 2 and all(math.isfinite(float(v)) for v in losses), losses
    saved = json.loads((out / "checkpoints" / "last" / "pretrained_model" / "train_config.json").read_text())
    assert saved["policy"]["use_amp"] is True and saved["optimizer"]["type"] == "adamw_fused"
