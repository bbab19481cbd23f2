"""LeRobot 0.6.1 integration: gym ids, the "bavo" EnvConfig, plugin discovery and `lerobot-eval`."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from _helpers import load_script
from lerobot.configs import FeatureType
from lerobot.envs.configs import EnvConfig
from lerobot.envs.factory import make_env, make_env_config
from lerobot.envs.utils import env_to_policy_features, preprocess_observation

import lerobot_bavo  # noqa: F401  (registers the gym ids; envs.configs below registers the "bavo" type)
from lerobot_bavo.envs import gym_id, register_envs
from lerobot_bavo.envs.conditions import CONDITIONS
from lerobot_bavo.envs.configs import BavoEnvConfig
from lerobot_bavo.envs.tasks import TASKS

REPO = Path(__file__).resolve().parents[1]
SMALL = {"image_height": 48, "image_width": 64, "n_points": 32}


# ----------------------------------------------------------------------------- registration
def test_gym_ids_registered_idempotently():
    for name in TASKS:
        assert gym_id(name) in gym.registry
        spec = gym.spec(gym_id(name))
        assert spec.entry_point == "lerobot_bavo.envs.bavo_env:BavoEnv"
        assert spec.kwargs == {"task": name}
        assert spec.max_episode_steps == TASKS[name].max_episode_steps
    assert register_envs() == []  # a second registration is a no-op
    assert gym_id("cube_handoff") == "lerobot_bavo/CubeHandoff-v0"
    with pytest.raises(ValueError, match="unknown task"):
        gym_id("pouring")


def test_plugin_discovery_imports_the_shim():
    names = {d.metadata["Name"] for d in importlib.metadata.distributions()}
    assert "lerobot_env_bavo" in names, "run `pip install -e .` so LeRobot's CLIs discover the plugin"
    from lerobot.utils.import_utils import register_third_party_plugins

    register_third_party_plugins()
    assert "lerobot_env_bavo" in sys.modules
    assert EnvConfig.get_choice_class("bavo") is BavoEnvConfig


# ----------------------------------------------------------------------------- config
def test_config_defaults_and_features():
    cfg = make_env_config("bavo")
    assert isinstance(cfg, BavoEnvConfig)
    assert cfg.type == "bavo" and cfg.task == "cube_handoff" and cfg.fps == 25
    assert cfg.package_name == "lerobot_bavo"
    assert cfg.gym_id == "lerobot_bavo/CubeHandoff-v0"
    assert cfg.gym_kwargs["max_episode_steps"] is None  # the task's registered limit
    assert set(cfg.features) == set(cfg.features_map)
    assert cfg.features["pixels/active"].shape == (240, 320, 3)
    assert cfg.features["point_cloud"].shape == (256, 6)

    feats = env_to_policy_features(BavoEnvConfig(**SMALL))
    assert feats["action"].type is FeatureType.ACTION and feats["action"].shape == (21,)
    assert feats["observation.state"].type is FeatureType.STATE and feats["observation.state"].shape == (21,)
    assert feats["observation.images.active"].type is FeatureType.VISUAL
    assert feats["observation.images.active"].shape == (3, 48, 64)  # CHW for policies
    assert feats["observation.point_cloud"].type is FeatureType.STATE
    assert feats["observation.point_cloud"].shape == (32, 6)
    assert feats["observation.point_pixels"].shape == (32, 2)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"task": "pouring"}, "unknown task 'pouring'; registered: cube_handoff, block_stacking"),
        ({"condition": "foggy"}, "unknown condition 'foggy'; registered: clean, stage, random"),
        ({"point_frame": "world"}, "unknown point_frame 'world'"),
        ({"episode_length": 0}, "episode_length must be >= 1"),
        ({"image_height": 8}, "image size"),
        ({"n_points": 0}, "n_points"),
        ({"fps": 50}, "25 Hz"),
        ({"render_mode": "human"}, "render_mode"),
    ],
)
def test_config_rejects_bad_values(kwargs, match):
    with pytest.raises(ValueError, match=match):
        BavoEnvConfig(**kwargs)


def test_config_accepts_every_benchmark_task_and_condition():
    assert list(TASKS)[:5] == [
        "cube_handoff",
        "block_stacking",
        "drawer_stowing",
        "slide_retrieval",
        "dustpan_sweeping",
    ]
    assert list(CONDITIONS)[:3] == ["clean", "stage", "random"]
    for task in TASKS:
        for condition in CONDITIONS:
            BavoEnvConfig(task=task, condition=condition)


# ----------------------------------------------------------------------------- envs
def test_gym_make_accepts_env_options():
    env = gym.make("lerobot_bavo/CubeHandoff-v0", image_height=96, image_width=128, n_points=64,
                   point_frame="camera", max_episode_steps=7)
    try:
        obs, info = env.reset(seed=0)
        assert obs["agent_pos"].shape == (21,) and obs["agent_pos"].dtype == np.float32
        assert obs["pixels"]["active"].shape == (96, 128, 3) and obs["pixels"]["active"].dtype == np.uint8
        assert obs["point_cloud"].shape == (64, 6) and obs["point_cloud"].dtype == np.float32
        assert obs["point_pixels"].shape == (64, 2) and obs["point_pixels"].dtype == np.int32
        assert env.unwrapped.obs_settings.point_frame == "camera"
        assert env.get_wrapper_attr("_max_episode_steps") == 7
        assert "is_success" in info
    finally:
        env.close()


def test_episode_length_longer_than_task_default_reaches_env():
    """gym.make consumes `max_episode_steps`; the env gets the same limit as `episode_length`."""
    cfg = BavoEnvConfig(episode_length=10_000, **SMALL)
    env = gym.make(cfg.gym_id, **cfg.gym_kwargs)
    try:
        assert env.get_wrapper_attr("_max_episode_steps") == 10_000
        assert env.unwrapped.max_episode_steps == 10_000
    finally:
        env.close()


def test_create_envs_step_and_preprocess():
    cfg = BavoEnvConfig(episode_length=5, **SMALL)
    envs = make_env(cfg, n_envs=1, use_async_envs=False)
    assert list(envs) == ["bavo"] and list(envs["bavo"]) == [0]
    vec = envs["bavo"][0]
    try:
        assert isinstance(vec, gym.vector.SyncVectorEnv)
        assert vec.call("_max_episode_steps")[0] == 5  # what lerobot-eval's rollout reads
        assert isinstance(vec.call("task_description")[0], str)
        obs, _ = vec.reset(seed=[0])
        home = obs["agent_pos"].copy()
        obs, reward, terminated, truncated, info = vec.step(home)
        assert reward.shape == (1,) and terminated.shape == (1,) and truncated.shape == (1,)
        assert "is_success" in info

        batch = preprocess_observation(obs)
        assert batch["observation.state"].shape == (1, 21)
        assert batch["observation.images.active"].shape == (1, 3, 48, 64)
        assert batch["observation.images.active"].dtype == torch.float32
        assert float(batch["observation.images.active"].max()) <= 1.0
        assert batch["observation.point_cloud"].shape == (1, 32, 6)
        assert batch["observation.point_pixels"].shape == (1, 32, 2)
        # Every env feature reaches the policy under its mapped name.
        assert set(env_to_policy_features(cfg)) - {"action"} == set(batch)
    finally:
        vec.close()


# ----------------------------------------------------------------------------- lerobot-eval
def _load_make_random_policy():
    return load_script("scripts/make_random_policy.py")


def test_make_random_policy_help():
    out = subprocess.run([sys.executable, str(REPO / "scripts" / "make_random_policy.py"), "--help"],
                         capture_output=True, text=True, timeout=60, check=True).stdout
    assert "--output-dir" in out and "--policy-type" in out


def test_lerobot_eval_end_to_end(tmp_path):
    """`lerobot-eval --env.type=bavo` with no plugin flags, on a random ACT checkpoint (~20 s)."""
    ckpt = _load_make_random_policy().make_random_policy(tmp_path / "policy", "act", **SMALL)
    assert (ckpt / "config.json").exists() and (ckpt / "policy_preprocessor.json").exists()

    cli = Path(sys.executable).with_name("lerobot-eval")
    cmd = [str(cli)] if cli.exists() else [sys.executable, "-m", "lerobot.scripts.lerobot_eval"]
    out_dir = tmp_path / "eval"
    cmd += [
        f"--policy.path={ckpt}",
        "--policy.device=cpu",
        "--env.type=bavo",
        "--env.task=cube_handoff",
        "--env.episode_length=10",
        f"--env.image_height={SMALL['image_height']}",
        f"--env.image_width={SMALL['image_width']}",
        f"--env.n_points={SMALL['n_points']}",
        "--eval.n_episodes=1",
        "--eval.batch_size=1",
        "--eval.use_async_envs=false",
        f"--output_dir={out_dir}",
    ]
    env = dict(
        os.environ,
        HF_HUB_OFFLINE="1",
        HF_HOME=str(tmp_path / "hf"),
        MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"),
        OPENBLAS_NUM_THREADS="1",
    )
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]

    info = json.loads((out_dir / "eval_info.json").read_text())
    overall = info["overall"]
    assert overall["n_episodes"] == 1
    assert 0.0 <= overall["pc_success"] <= 100.0
    assert 0.0 <= overall["avg_max_reward"] <= 1.0
    assert info["per_task"][0]["task_group"] == "bavo"


def test_config_with_privileged_object_poses():
    """`environment_state=True` adds the object poses (7 per object) as an ENV feature mapped to
    observation.environment_state, and passes the flag to the env."""
    cfg = BavoEnvConfig(**SMALL, environment_state=True)
    assert set(cfg.features) == set(cfg.features_map)
    assert cfg.features["environment_state"].shape == (14,)  # cube + plate
    assert cfg.gym_kwargs["environment_state"] is True
    feats = env_to_policy_features(cfg)
    assert feats["observation.environment_state"].type is FeatureType.ENV
